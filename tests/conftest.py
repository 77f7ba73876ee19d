"""Shared test helpers: the paper's equilibrium error recomputed from scratch, and the shared
independent checker.

Both are independent of the package under test (plain numpy, or a separate script), so a test
that uses them checks the physics, not the project's own bookkeeping:

* :func:`relative_residuals` and friends — eqs. (2)-(3) at every non-support vertex,
  ``‖Σ_j w_ij (v_j − v_i) − (0, 0, L_i)‖ / |L_i|`` (the Table 1 metric), from arrays, from a
  network object or from a JSON network document (docs/reference/formats.md);
* :func:`independent_check` — runs ``shared/tools/check_network.py`` (which sits beside the
  repository: ``<repo>/../shared``, in a developer's tree and in CI's fresh clone alike) on a
  file, document or network and returns its parsed report; the test is skipped, with a reason,
  where the checker is absent. Decorate with :data:`requires_checker` to skip before expensive
  fixtures are built;
* :func:`time_limit_bound` — how long a run with a time limit may take, with the margin for one
  uninterruptible step stretched by the machine's load (the suite runs on loaded 2-core machines).

Test modules import them: ``from tests.conftest import independent_check, document_errors``.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np
import pytest

SHARED = Path(__file__).resolve().parents[2] / "shared"
CHECKER = SHARED / "tools" / "check_network.py"
CHECKER_MISSING = f"the shared independent checker is not beside the repository (no {CHECKER})"
#: skip marker for tests that need the shared checker
requires_checker = pytest.mark.skipif(not CHECKER.is_file(), reason=CHECKER_MISSING)


# ------------------------------------------------------------------ a long design edit
@pytest.fixture
def slow_subdivide(monkeypatch):
    """``Subdivide`` edits that block until released: ``(started, release)`` events; the edit
    sets ``started`` when it begins and returns the design unchanged once ``release`` is set (or
    after 20 s). Released when the test ends."""
    import threading

    from selfsupport.design import edits as edits_mod

    started, release = threading.Event(), threading.Event()

    def slow_apply(self, design):
        started.set()
        release.wait(20)
        return design

    monkeypatch.setattr(edits_mod.Subdivide, "apply", slow_apply)
    yield started, release
    release.set()


# ------------------------------------------------------------------ wall-clock bounds under load
def load_factor() -> float:
    """How many times longer a CPU-bound step takes now than on an idle machine, at least 1: the
    one-minute load average per core (6 on 2 cores gives 3)."""
    return max(1.0, os.getloadavg()[0] / (os.cpu_count() or 1))


def time_limit_bound(limit: float, overshoot: float = 1.0) -> float:
    """The longest a run with time limit ``limit`` [s] may take: the limit (the deadline is wall
    time, so the load does not move it), plus 10% of it and ``overshoot`` seconds for the step
    running when it passes — the product's promise on an idle machine, stretched by
    :func:`load_factor` for that step, which the load slows."""
    return limit + (0.1 * limit + overshoot) * load_factor()


# ------------------------------------------------------------------ the equilibrium error, plain numpy
def relative_residuals(V: Any, E: Any, w: Any, L: Any, sup: Any) -> np.ndarray:
    """Per non-support vertex ``‖Σ_j w_ij (v_j − v_i) − (0, 0, L_i)‖ / |L_i|`` (eqs. 2-3, the
    paper's Table 1 metric). ``L`` is the signed vertical load per vertex, ``sup`` a boolean
    mask. A zero load gives inf/nan, which fails any ``<=`` comparison. ``L`` may also be one load
    vector per vertex ``(n, 3)`` (horizontal loads): then ``‖Σ_j w_ij (v_j − v_i) − L_i‖ / ‖L_i‖``."""
    V = np.asarray(V, float)
    E = np.asarray(E, int)
    w = np.asarray(w, float)
    L = np.asarray(L, float)
    free = ~np.asarray(sup, bool)
    r = np.zeros_like(V)
    f = w[:, None] * (V[E[:, 1]] - V[E[:, 0]])
    np.add.at(r, E[:, 0], f)
    np.add.at(r, E[:, 1], -f)
    if L.ndim == 2:
        r -= L
        size = np.linalg.norm(L, axis=1)
    else:
        r[:, 2] -= L
        size = np.abs(L)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.linalg.norm(r[free], axis=1) / size[free]


def max_relative_error(V: Any, E: Any, w: Any, L: Any, sup: Any) -> float:
    """Max of :func:`relative_residuals`."""
    return float(relative_residuals(V, E, w, L, sup).max())


def roundoff_scale(V: Any, E: Any, w: Any, L: Any, sup: Any) -> np.ndarray:
    """Per non-support vertex ``ε Σ_j w_ij (‖v_i‖ + ‖v_j‖) / |L_i|``: the relative error that
    rounding the coordinates alone puts into :func:`relative_residuals` (each term w_ij (v_j − v_i)
    carries ~ε w_ij (‖v_i‖ + ‖v_j‖)). No residual evaluated in floating point — and no network
    computed in it — is reliably below a small multiple of this."""
    V = np.asarray(V, float)
    E = np.asarray(E, int)
    w = np.abs(np.asarray(w, float))
    size = np.linalg.norm(V, axis=1)
    t = w * (size[E[:, 0]] + size[E[:, 1]])
    s = np.zeros(len(V))
    np.add.at(s, E[:, 0], t)
    np.add.at(s, E[:, 1], t)
    free = ~np.asarray(sup, bool)
    return np.finfo(float).eps * s[free] / np.abs(np.asarray(L, float)[free])


def hidden_displacement(V: Any, E: Any, w: Any, L: Any, sup: Any, rel: float) -> np.ndarray:
    """Per non-support vertex, the largest coordinate change a relative residual ``rel`` can hide:
    ``rel · K_ff⁻¹ |L_f|``, with ``K_ff`` the stress Laplacian of the free vertices
    (``(K x)_i = Σ_j w_ij (x_i − x_j)``). With w ≥ 0 and every component tied to a support K_ff is
    a nonsingular M-matrix, so K_ff⁻¹ ≥ 0 entrywise and a residual r with ‖r_i‖ ≤ rel |L_i|
    moves each coordinate by |K_ff⁻¹ r| ≤ rel K_ff⁻¹ |L|. (With the supports at z = 0,
    K_ff⁻¹ |L| is exactly the height of the network: the bound is ``rel`` × height.)"""
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve

    V = np.asarray(V, float)
    E = np.asarray(E, int)
    w = np.asarray(w, float)
    free = ~np.asarray(sup, bool)
    n = len(V)
    i, j = E[:, 0], E[:, 1]
    K = sp.coo_matrix((np.r_[w, w, -w, -w], (np.r_[i, j, i, j], np.r_[i, j, j, i])), shape=(n, n)).tocsr()
    Kff = K[free][:, free].tocsc()
    return rel * spsolve(Kff, np.abs(np.asarray(L, float)[free]))


def network_errors(net: Any, weights: Any = None) -> np.ndarray:
    """:func:`relative_residuals` of a network object (``vertices, edges, weights, loads,
    supports``), optionally with other ``weights``."""
    return relative_residuals(net.vertices, net.edges, net.weights if weights is None else weights,
                              net.loads, net.supports)


def document_arrays(d: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``V, E, w, L, supports-mask`` of a JSON network document (docs/reference/formats.md)."""
    V = np.asarray(d["vertices"], float)
    sup = np.zeros(len(V), bool)
    sup[np.asarray(d["supports"], int)] = True
    return V, np.asarray(d["edges"], int), np.asarray(d["weights"], float), np.asarray(d["loads"], float), sup


def document_errors(d: dict) -> np.ndarray:
    """:func:`relative_residuals` of a JSON network document as written."""
    return relative_residuals(*document_arrays(d))


def document_floors(d: dict) -> np.ndarray:
    """Per non-support vertex of a JSON network document, the relative error that rounding its
    coordinates to doubles can leave, ``eps ‖Σ_j |w_ij| (|v_i| + |v_j|)‖ / |L_i|`` (per
    coordinate; :func:`selfsupport.core.evidence.roundoff_floors`, recomputed here as
    :func:`relative_residuals` sums the forces)."""
    V, E, w, L, sup = document_arrays(d)
    a = np.abs(w)[:, None] * (np.abs(V[E[:, 0]]) + np.abs(V[E[:, 1]]))
    S = np.zeros_like(V)
    np.add.at(S, E[:, 0], a)
    np.add.at(S, E[:, 1], a)
    with np.errstate(divide="ignore"):
        return np.finfo(float).eps * np.linalg.norm(S[~sup], axis=1) / np.abs(L[~sup])


def face_area(V: Any, faces: list[list[int]]) -> float:
    """Total area with every face triangulated as a fan around its centroid (as the shared checker
    does: non-planar quads have no other canonical area)."""
    V = np.asarray(V, float)
    area = 0.0
    for face in faces:
        P = V[np.asarray(face, int)]
        c = P.mean(axis=0)
        area += 0.5 * np.linalg.norm(np.cross(P - c, np.roll(P, -1, axis=0) - c), axis=1).sum()
    return float(area)


def document_check(d: dict) -> dict[str, Any]:
    """Equilibrium and load of a network document recomputed from scratch: ``max_rel`` (the max
    relative error over non-supports), ``min_w``, ``total_load``, ``area`` (self-weight of the
    written geometry per unit ρtg, see :func:`face_area`) and the ``supports`` mask."""
    V, E, w, L, sup = document_arrays(d)
    return {"max_rel": float(relative_residuals(V, E, w, L, sup).max()), "min_w": float(w.min()),
            "total_load": float(L.sum()), "area": face_area(V, d["faces"]), "supports": sup}


# ------------------------------------------------------------------ the shared independent checker
@dataclass(frozen=True)
class CheckerReport:
    """The shared checker's verdict: exit code, ``ok`` (its last line), and every ``key=value``
    it printed as a float (``vertices edges supports min_w max_rel_error max_abs_residual``, and
    with a unit weight ``total_load expected load_rel_diff``)."""

    returncode: int
    ok: bool
    values: dict[str, float] = field(default_factory=dict)
    stdout: str = ""

    def __getitem__(self, key: str) -> float:
        return self.values[key]

    @property
    def max_rel_error(self) -> float:
        return self.values["max_rel_error"]


def independent_check(target: Any, *, tol: float | None = None, unit_weight: float | None = None,
                      load_tol: float | None = None, allow_tension: bool = False,
                      timeout: float = 120) -> CheckerReport:
    """Run ``shared/tools/check_network.py`` on ``target`` — a JSON file path, a network document
    (dict), a :class:`~selfsupport.core.result.Network` or a :class:`~selfsupport.core.result.SolveResult` —
    with the checker's own options (``--tol``, its default 1e-4; ``--unit-weight`` ρtg;
    ``--load-tol``; ``--allow-tension``: negative weights are counted, ``tension_edges``, not
    refused) and return its parsed report. Skips the test when the checker is absent."""
    if not CHECKER.is_file():
        pytest.skip(CHECKER_MISSING)
    with tempfile.TemporaryDirectory(prefix="checker-") as tmp:
        if isinstance(target, (str, Path)):
            path = Path(target)
        else:
            path = Path(tmp) / "network.json"
            if isinstance(target, dict):
                path.write_text(json.dumps(target), encoding="utf-8")
            else:
                from selfsupport.io import write_network

                write_network(path, target)
        cmd = [sys.executable, str(CHECKER), str(path)]
        for flag, value in (("--tol", tol), ("--unit-weight", unit_weight), ("--load-tol", load_tol)):
            if value is not None:
                cmd += [flag, repr(float(value))]
        if allow_tension:
            cmd.append("--allow-tension")
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    if p.returncode not in (0, 1):  # 1 is its verdict "FAIL"; anything else is a crash
        raise AssertionError(f"the shared checker crashed ({p.returncode}):\n{p.stdout}{p.stderr}")
    values = {}
    for token in p.stdout.split():
        key, eq, value = token.partition("=")
        if eq:
            values[key] = float(value)
    lines = p.stdout.strip().splitlines()
    return CheckerReport(returncode=p.returncode, ok=bool(lines) and lines[-1] == "ok", values=values,
                         stdout=p.stdout + p.stderr)


def kkt_residual(nlp: dict, x: np.ndarray, p: np.ndarray, lam_x: np.ndarray, lam_g: np.ndarray) -> float:
    """Relative stationarity residual of an NLP at a solver's answer.

    CasADi's Lagrangian is ``f + lam_gᵀ g + lam_xᵀ x``, so at a KKT point
    ``∇f + J_gᵀ lam_g + lam_x = 0``. Returns ``‖∇f + J_gᵀ lam_g + lam_x‖_∞`` divided by the
    largest of the three terms' max-norms: relative to the forces that must cancel, with no
    absolute floor (objective gradients here are often 1e-8 or smaller: a floor of 1 would
    pass any multipliers).

    Parameters
    ----------
    nlp
        The NLP dict handed to ``ca.nlpsol`` (``x``, ``p``, ``f``, ``g``).
    x, p, lam_x, lam_g
        The solver's answer, the parameters of that solve and its multipliers.
    """
    X, P = nlp["x"], nlp["p"]
    F = ca.Function("kkt", [X, P], [ca.gradient(nlp["f"], X), ca.jacobian(nlp["g"], X)])
    gf, Jg = F(np.asarray(x, float), np.asarray(p, float))
    gf = np.asarray(gf).ravel()
    JtL = np.asarray(Jg.T @ ca.DM(np.asarray(lam_g, float))).ravel()
    lx = np.asarray(lam_x, float).ravel()
    scale = max(np.abs(gf).max(initial=0.0), np.abs(JtL).max(initial=0.0), np.abs(lx).max(initial=0.0), 1e-300)
    return float(np.abs(gf + JtL + lx).max(initial=0.0) / scale)
