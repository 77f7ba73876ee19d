"""Variants of a scene that no solver setting was chosen on: a held-out check at hand.

The project's solver settings are general, and there are held-out scenes of the same kind as
the paper's. This registry makes such scenes from any scene: each variant maps the vertex
positions (z up) and keeps the mesh, the supports and the loads' definition. ``studies.subdivided
--variants`` runs them (also subdivided):

- ``turned``: turned by 1.1 rad about the vertical, scaled by 2.5 and moved by (30, −12, 5) m. A
  similarity, so the network should be the original's, turned, scaled and moved (its distance
  to the reference 2.5× as many metres; over the axis-aligned diagonal, which turning changes,
  not the same number);
- ``flat`` / ``tall``: heights above the lowest vertex scaled by 0.6 / 1.6 (other thrusts);
- ``bumpy``: smooth bumps of 1% of the top-view diagonal added to the heights;
- ``mirrored``: x → −x, which reverses the faces' orientation in the top view.

Example (run by ``tests/test_studies.py``)
------------------------------------------
>>> V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.5], [0.0, 2.0, 1.0]])
>>> W = VARIANTS["turned"](V)
>>> d = lambda P: np.linalg.norm(P[:, None] - P[None], axis=-1)
>>> bool(np.allclose(d(W), 2.5 * d(V)))
True
>>> VARIANTS["tall"](V)[:, 2].tolist()
[0.0, 0.8, 1.6]
"""
from __future__ import annotations

import dataclasses
from typing import Any, Callable

import numpy as np

TURN, SCALE, SHIFT = 1.1, 2.5, np.array([30.0, -12.0, 5.0])


def _turned(V: np.ndarray) -> np.ndarray:
    c, s = np.cos(TURN), np.sin(TURN)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return SCALE * V @ R.T + SHIFT


def _heights(factor: float) -> Callable[[np.ndarray], np.ndarray]:
    def f(V: np.ndarray) -> np.ndarray:
        W = V.copy()
        W[:, 2] = V[:, 2].min() + factor * (V[:, 2] - V[:, 2].min())
        return W
    return f


def _bumpy(V: np.ndarray) -> np.ndarray:
    lo = V[:, :2].min(axis=0)
    diag = float(np.linalg.norm(np.ptp(V[:, :2], axis=0)))
    u, v = ((V[:, :2] - lo) / diag).T
    W = V.copy()
    W[:, 2] += 0.01 * diag * (np.sin(7.3 * u + 1.0) * np.cos(5.1 * v + 0.3) + 0.5 * np.sin(11.9 * v + 2.0 * u))
    return W


def _mirrored(V: np.ndarray) -> np.ndarray:
    W = V.copy()
    W[:, 0] = -W[:, 0]
    return W


#: variant name -> map of the (n, 3) vertex positions
VARIANTS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "none": lambda V: V,
    "turned": _turned,
    "flat": _heights(0.6),
    "tall": _heights(1.6),
    "bumpy": _bumpy,
    "mirrored": _mirrored,
}


def variant_scene(scene: Any, name: str) -> Any:
    """``scene`` with its vertices mapped by ``VARIANTS[name]`` (mesh, supports, loads kept)."""
    if name == "none":
        return scene
    return dataclasses.replace(scene, mesh=scene.mesh.with_vertices(VARIANTS[name](np.asarray(scene.mesh.vertices))),
                               name=f"{scene.name}-{name}")
