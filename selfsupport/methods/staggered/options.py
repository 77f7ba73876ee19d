"""The staggered method's settings and their parsing from ``KEY=VALUE`` text."""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Mapping

import numpy as np

from selfsupport.core.errors import InputError
from selfsupport.core.options import check_options, check_range
from selfsupport.methods.staggered.step3 import STEP_RTOL

#: The objective when the problem leaves it to the method: distance to the reference surface
#: (with the weak tangential hold τ of :data:`formulations.terms.TANGENTIAL`).
DEFAULT_OBJECTIVE: dict[str, float] = {"reference": 1.0}


def _setting(default: Any, interval: str) -> Any:
    """A numeric setting with its allowed interval (checked by :func:`selfsupport.core.options.check_range`)."""
    return field(default=default, metadata={"range": interval})


@dataclass(frozen=True)
class StaggeredOptions:
    """Settings of the staggered method (general: no per-scene tuning). Each numeric setting
    carries its allowed interval (``--option`` values outside it are refused)."""

    alpha0: float = _setting(1.0, "(0, inf)")  # weight of the objective (distance to the reference, ...) at the start
    beta0: float = _setting(0.01, "(0, inf)")  # proximal penalty at the start
    shrink: float = _setting(0.5, "(0, 1)")  # factor applied to α, β after an iteration that reduced the error
    # (and to α from the third rejected step in a row)
    alpha_min: float = _setting(1e-8, "(0, inf)")
    beta_min: float = _setting(1e-8, "(0, inf)")
    max_rejections: int = _setting(12, "[1, inf)")  # consecutive rejected position steps before "stalled"
    creep_window: int = _setting(10, "[0, inf)")  # iterations at alpha_min in which the fit error must halve,
    # else Step 3 turns coupled for the rest of the run (free top view; 0: never)
    stall_window: int = _setting(30, "[1, inf)")  # iterations at alpha_min in which the fit error must halve,
    # else "stalled" (schedule.fit_stalls)
    smoothing: float = _setting(100.0, "[0, inf)")  # γ/α: Step 3's smooth-displacement term (the Fairness
    # term on v − v_ref, the original tool's smoothing; docs/theory/staggered.md)
    step_rtol: float = _setting(STEP_RTOL, "(0, 1)")  # Step 3's conjugate gradients stop at this residual,
    # relative to the step's own (step3.STEP_RTOL)
    reproject_every: int = _setting(1, "[0, inf)")  # closest-point re-projection onto the reference (0: never)
    prox_w: float = _setting(1e-8, "(0, inf)")  # proximal weight of the Step-2 fit relative to its diagonal:
    # makes the weights unique (A has more columns than rows) and reproducible during the iteration
    prox_w_final: float = _setting(1e-12, "(0, inf)")  # ... and for the last fit before the polish
    polish_tol: float = _setting(1e-3, "(0, inf)")  # fit error below which the weights are frozen, positions solved
    joint_polish_tol: float = _setting(1e-2, "(0, inf)")  # ... and the joint polish is tried (several load
    # cases, a fixed top view, a hull): it moves the weights with the positions, a Newton iteration that
    # converges from farther
    coupled: bool | None = None  # Step 3 moves the free weights with the positions (Gauss-Newton on min_w E):
    # closer to the reference, but slower and less reproducible under rotation/scaling of the input; hence
    # opt-in. None (default): off, except where it is tried first (method._couples_first)
    continuation: bool = True  # load cases that are not proportional: first the continuation from the cases'
    # envelope (cases.py), then, when it is blocked, the iteration over every case at once
    ipopt_finish: bool = True  # ... and when that does not converge either, IPOPT over every case jointly,
    # warm-started from its network, in the time left (cases.ipopt_finish)
    coupled_damping: float = _setting(1e-4, "[0, inf)")  # coupled step: how strongly weights near ε are held
    finish_try: float = _setting(0.1, "[0, inf)")  # fit error below which the polish is tried after every step
    warm_accept: float = _setting(0.5, "[0, inf)")  # a warm start whose first fit error is above finish_try but
    # below this gets one finish try as it is, and the solve starts cold when that fails (iterating on from
    # such a start is slower than a cold start)
    warm_iterate: bool = False  # a warm start above warm_accept is iterated from (not restarted cold):
    # a prolongation from a coarser level (methods/multilevel.py), near the solution yet not in equilibrium
    finish_slack: float = _setting(0.05, "[0, inf)")  # ... kept if its mean distance grows by at most this
    finish_slack_released: float = _setting(0.25, "[0, inf)")  # ... once α is at alpha_min: the reference no
    # longer holds the iterate, and iterating on buys little closeness
    finish_screen: float = _setting(0.25, "[0, inf]")  # ... and not even polished when one stress-Laplacian
    # solve with the iterate's loads already moves the mean distance up by more than this (finish.screen_ratio)
    try_fallbacks: bool = False  # ... with Newton only (no Anderson / Newton-Krylov rounds after it)
    fit_rtol: float = _setting(1e-3, "(0, inf)")  # KKT tolerance a Step-2 backend may stop at while the fit
    # error is above finish_try (those fits only steer the iteration; the fits the finish uses are exact)
    refine: int = _setting(0, "[0, inf)")  # at most this many SQP steps towards the objective's optimum after
    # convergence (refine.py; 0: the paper's method as it is)
    refine_concentrated: int = _setting(20, "[0, inf)")  # ... the steps when ``refine`` is 0 and a load case
    # holds point loads or extra masses: the penalty path carries such a load by a spike far from the reference
    refine_gain: float = _setting(1e-2, "[0, 1)")  # ... stopping after two steps that each lower the objective
    # by less than this (relative; 0: on to refine's step limit, the optimum of the problem's objective)
    tol: float = _setting(1e-9, "(0, inf)")  # required max relative error of the final network
    max_iter: int = _setting(200, "[1, inf)")
    time_limit: float = _setting(600.0, "[0, inf)")  # (0: stop after the first fit, with the network so far)


def parse_option(text: str) -> tuple[str, Any]:
    """``"KEY=VALUE"`` → a typed :class:`StaggeredOptions` setting (the CLI's ``--option``).

    >>> parse_option("coupled=true"), parse_option("shrink=0.25")
    (('coupled', True), ('shrink', 0.25))

    Values outside the interval in the field's ``metadata["range"]`` are refused
    (:func:`selfsupport.core.options.check_range`).
    """
    key, sep, value = text.partition("=")
    key, value = key.strip().replace("-", "_"), value.strip()
    fields = StaggeredOptions.__dataclass_fields__
    if not sep or key not in fields:
        raise InputError(f"--option needs KEY=VALUE with KEY one of {sorted(fields)}, got {text!r}")
    kind = str(fields[key].type)
    try:
        if kind in ("bool", "bool | None"):
            if value.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError(value)
            return key, value.lower() in ("true", "1", "yes")
        number = int(value) if kind == "int" else float(value)
    except ValueError:
        raise InputError(f"--option {key} needs a {kind} value, got {value!r}") from None
    if not np.isfinite(number):
        raise InputError(f"--option {key} must be finite, got {value!r}")
    check_range(key, number, fields[key].metadata.get("range"))  # the interval next to the field
    return key, number


def _options(base: StaggeredOptions, overrides: Mapping[str, Any]) -> StaggeredOptions:
    unknown = set(overrides) - set(StaggeredOptions.__dataclass_fields__)
    if unknown:
        raise InputError(f"unknown staggered option(s) {sorted(unknown)}; known: "
                         f"{sorted(StaggeredOptions.__dataclass_fields__)}")
    check_options(StaggeredOptions, overrides)
    return replace(base, **overrides) if overrides else base
