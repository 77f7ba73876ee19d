"""The deadline every inner loop honours (``--time-limit``).

A solve turns its time limit into one deadline, a ``time.perf_counter()`` value, and passes it
down explicitly (keyword ``deadline=``; ``None`` means none) to every loop that can run long:
Step 2's iterations, Step 3's conjugate gradients, the polishes, the refinement and IPOPT.
Checking once per outer iteration was not enough: at 200k vertices one Step-2 fit took 44 s
and the polish 23 s, so ``--time-limit 10`` ran 120 s.
"""
from __future__ import annotations

import time


class DeadlineReached(Exception):
    """Raised inside a loop that cannot return a partial result (Step 3's conjugate gradients);
    the solve catches it and stops with status ``"time_limit"`` and its best network so far."""


def out_of_time(deadline: float | None, step_seconds: float = 0.0) -> bool:
    """Whether ``deadline`` has passed, or would pass before another step of ``step_seconds``
    ends. Loops check it before each step with the duration of their last one, so that a long
    step (one factorization at 200k vertices takes seconds) does not overrun by its length.

    >>> out_of_time(None), out_of_time(time.perf_counter() + 60), out_of_time(time.perf_counter() + 60, 120)
    (False, False, True)
    """
    return deadline is not None and time.perf_counter() + step_seconds > deadline


def remaining(deadline: float | None, default: float = float("inf")) -> float:
    """Seconds left before ``deadline`` (``default`` when there is none), at least 0."""
    return default if deadline is None else max(deadline - time.perf_counter(), 0.0)


def ipopt_stop_callback(nx: int, ng: int, n_p: int):
    """A CasADi ``iteration_callback`` for IPOPT that requests a stop once its ``deadline``
    attribute (``time.perf_counter()``; ``None``: none) has passed, or would pass before another
    iteration as long as the last one ends (:func:`out_of_time`; one iteration of IPOPT over three
    load cases on cas took over 10 s) — for a solver built once and called many times, whose
    ``max_wall_time`` is fixed when it is built. Setting ``deadline`` starts a new count of the
    iterations' durations. IPOPT then returns ``User_Requested_Stop`` with its current iterate,
    and ``stopped`` is true (it tells a stop for the deadline from other stops)."""
    import casadi as ca

    class _Stop(ca.Callback):
        def __init__(self) -> None:
            ca.Callback.__init__(self)
            self._deadline: float | None = None
            self._last: float | None = None  # (the time of the last iteration's call)
            self.stopped = False
            self.construct("deadline_stop", {})

        @property
        def deadline(self) -> float | None:
            return self._deadline

        @deadline.setter
        def deadline(self, value: float | None) -> None:
            self._deadline, self._last, self.stopped = value, None, False

        def get_n_in(self) -> int:
            return ca.nlpsol_n_out()

        def get_n_out(self) -> int:
            return 1

        def get_name_in(self, i: int) -> str:
            return ca.nlpsol_out(i)

        def get_name_out(self, i: int) -> str:
            return "ret"

        def get_sparsity_in(self, i: int):
            size = {"f": 1, "x": nx, "lam_x": nx, "g": ng, "lam_g": ng, "p": n_p, "lam_p": n_p}.get(ca.nlpsol_out(i))
            return ca.Sparsity.dense(size) if size is not None else ca.Sparsity(0, 0)

        def eval(self, arg):  # nonzero: IPOPT stops
            now = time.perf_counter()
            step = 0.0 if self._last is None else now - self._last  # (the first call follows the set-up)
            self._last = now
            self.stopped = out_of_time(self._deadline, step)
            return [1 if self.stopped else 0]

    return _Stop()


#: Seconds per vertex that finishing takes once the solve has stopped: the final polish, the
#: networks, the objective terms and the distance evidence (one closest-point index and one
#: query), the JSON text and its write: about 1.5x what ``python -m studies.fixed_costs`` measures
#: on a 2-core machine, because a loaded machine is slower at the end of a run too.
FINISH_SECONDS_PER_VERTEX = 2e-5


def finish_reserve(n_vertices: int, n_cases: int = 1) -> float:
    """Seconds to keep free at the end of a time limit for the work after the solve (building
    the result and writing it), so that a whole run ends near its limit: 4 s at 200k vertices,
    0.02 s at 1k. Each load case has its network, evidence and weights in the file (300 cases on
    a 91-vertex dome: 0.7 s), so the reserve counts vertices times cases.

    >>> finish_reserve(200_000), finish_reserve(1_000), finish_reserve(100, 300)
    (4.0, 0.02, 0.6)
    """
    return FINISH_SECONDS_PER_VERTEX * float(n_vertices) * max(int(n_cases), 1)
