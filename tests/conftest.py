"""Shared test helpers."""
from __future__ import annotations

import casadi as ca
import numpy as np


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
