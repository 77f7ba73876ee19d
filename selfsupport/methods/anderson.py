"""Anderson acceleration of a fixed point ``u = G(u)``, shared by every fixed-point loop of the
methods: the polish's height iteration (:mod:`~selfsupport.methods.polish`) and the simultaneous
method's load rounds (:mod:`~selfsupport.methods.simultaneous`).

:class:`Anderson` is one mixing step (type II: the least-squares combination of the last
``depth`` differences); :func:`anderson` iterates it on a cheap map with a tolerance, a round
limit, a deadline and a give-up rule for a diverging iteration.

Example
-------
>>> import numpy as np
>>> A = np.array([[0.0, 1.1], [-1.1, 0.0]])  # a rotation that grows: plain iteration diverges
>>> u, rounds, converged = anderson(lambda u: A @ u + 1.0, np.zeros(2), tol=1e-12, max_rounds=30)
>>> converged, bool(np.allclose(u, A @ u + 1.0))
(True, True)
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from selfsupport.methods.deadline import out_of_time

#: Differences mixed by :func:`anderson` unless told otherwise.
DEPTH = 5
#: From this round on, :func:`anderson` gives up when the fixed-point residual exceeds the first
#: round's: the iteration diverges, and a method that does not need a contraction should take over.
DIVERGING_FROM = 15


class Anderson:
    """One Anderson mixing step per call of :meth:`next`.

    Parameters
    ----------
    depth
        Differences kept (0: the plain iteration ``u ← G(u)``).
    accept
        Vetoes a mixed iterate (then the plain ``G(u)`` is returned), e.g. loads that must stay
        downward.
    limit_step
        Also veto a mixed iterate farther from ``G(u)`` than ``G(u)`` is from ``u`` (against a
        runaway when the map is far from contractive).
    """

    def __init__(self, depth: int = DEPTH, *, accept: Callable[[np.ndarray], bool] | None = None,
                 limit_step: bool = False) -> None:
        self.depth = int(depth)
        self.accept = accept
        self.limit_step = limit_step
        self._du: list[np.ndarray] = []
        self._df: list[np.ndarray] = []
        self._last: tuple[np.ndarray, np.ndarray] | None = None

    def next(self, u: np.ndarray, Gu: np.ndarray) -> np.ndarray:
        """The next iterate from ``u`` and its image ``G(u)``."""
        f = Gu - u
        if self._last is not None and self.depth > 0:
            self._du.append(u - self._last[0])
            self._df.append(f - self._last[1])
            del self._du[:-self.depth], self._df[:-self.depth]
        self._last = (np.array(u, float), f)
        if not self._df:
            return Gu
        dF = np.stack(self._df, axis=1)
        gamma = np.linalg.lstsq(dF, f, rcond=None)[0]
        out = u + f - (np.stack(self._du, axis=1) + dF) @ gamma
        too_far = self.limit_step and np.abs(out - Gu).max() > np.abs(f).max()
        if too_far or not np.all(np.isfinite(out)) or (self.accept is not None and not self.accept(out)):
            return Gu
        return out


def anderson(G: Callable[[np.ndarray], np.ndarray], u: np.ndarray, *, tol: float, max_rounds: int,
             depth: int = DEPTH, deadline: float | None = None) -> tuple[np.ndarray, int, bool]:
    """Anderson-accelerated iteration of ``u ← G(u)`` from ``u``.

    Parameters
    ----------
    G
        The map (each call one round).
    u
        Start.
    tol
        Converged when ``max |G(u) − u| ≤ tol``.
    max_rounds
        Most evaluations of ``G``.
    depth
        Differences mixed (:class:`Anderson`).
    deadline
        ``time.perf_counter()`` value checked before every round.

    Returns
    -------
    ``(point, rounds, converged)``: ``G(u)`` when converged; the start at the deadline (only a
    converged point is known to be better); the current iterate when it gives up
    (:data:`DIVERGING_FROM`) or runs out of rounds.
    """
    mixer = Anderson(depth)
    start, first = u, np.inf
    for rounds in range(1, max_rounds + 1):
        if out_of_time(deadline):
            return start, rounds - 1, False
        Gu = G(u)
        res = float(np.abs(Gu - u).max())
        if res <= tol:
            return Gu, rounds, True
        first = res if rounds == 1 else first
        if rounds >= DIVERGING_FROM and res > first:
            return u, rounds, False
        u = mixer.next(u, Gu)
    return u, max_rounds, False
