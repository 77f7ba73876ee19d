"""The figures and the interactive view of a solve, written next to its network.

``selfsupport solve --report DIR`` and ``selfsupport demo`` call :func:`write_report`::

    files = write_report(result, "out/")          # out/network.png, ..., out/view.html
    print(files.markdown())                        # links for a Markdown report

The Airy analysis is computed once and shared by the airy / reciprocal / directions figures
and the view. A figure that cannot be drawn for this network (no reference surface, no
history, an analysis that does not apply) is skipped with its reason instead of failing
the solve that has already succeeded.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from selfsupport.core.errors import InputError, SelfSupportError
from selfsupport.core.result import Network, SolveResult
from selfsupport.figures.render import FIGURES, FigureInput, airy_of, directions_of, render_png_bytes
from selfsupport.figures.viewer import write_view
from selfsupport.io.atomic import atomic_write_bytes

__all__ = ["REPORT_KINDS", "ReportFiles", "write_report", "stored_thickness", "network_title"]

#: figure kinds written by default, in this order; file name = ``<kind>.png``
REPORT_KINDS: tuple[str, ...] = ("network", "deviation", "history", "airy", "reciprocal", "directions", "reactions")
#: kinds that need the Airy analysis / the principal directions
_NEEDS_AIRY = ("airy", "reciprocal")
_NEEDS_DIRECTIONS = ("directions",)
#: errors that mean "this figure does not apply here" (not a bug): skipped with the reason
_SKIPPABLE = (SelfSupportError, ValueError, ArithmeticError, np.linalg.LinAlgError)


@dataclass(frozen=True)
class ReportFiles:
    """What :func:`write_report` wrote (kind -> path) and what it skipped (kind -> reason)."""

    directory: Path
    figures: dict[str, Path]
    view: Path | None
    skipped: dict[str, str] = field(default_factory=dict)

    def markdown(self) -> str:
        """A Markdown section linking the files (paths relative to the directory)."""
        lines = ["## Figures", ""]
        if self.view is not None:
            lines += [f"Interactive view (opens offline in a browser): [{self.view.name}]({self.view.name})", ""]
        for kind, p in self.figures.items():
            lines += [f"![{kind}]({p.name})", ""]
        for kind, why in self.skipped.items():
            lines.append(f"* {kind}: not drawn — {why}")
        return "\n".join(lines).rstrip() + "\n"


def stored_thickness(parameters: Mapping[str, Any] | None) -> float | None:
    """The shell thickness a solve used (``parameters["loads"]["thickness"]``, as ``api.solve``
    stores it), or ``None``."""
    loads = (parameters or {}).get("loads")
    t = loads.get("thickness") if isinstance(loads, Mapping) else None
    return float(t) if isinstance(t, (int, float)) and math.isfinite(t) and t > 0 else None


def network_title(name: str | None, result: SolveResult | None) -> str:
    """``"name (method, status)"`` for figure titles."""
    head = name or "thrust network"
    return head if result is None else f"{head} ({result.method}, {result.status})"


def write_report(result: SolveResult | Network, directory: str | Path, *, name: str | None = None,
                 thickness: float | None = None, kinds: Sequence[str] = REPORT_KINDS, view: bool = True,
                 history: Sequence[Mapping[str, Any]] | None = None, dpi: int = 150) -> ReportFiles:
    """Write ``<kind>.png`` for each figure kind and ``view.html`` into ``directory``.

    Parameters
    ----------
    result
        A solve result (its history and parameters are used) or a bare network.
    directory
        Created if missing; existing files of the same names are replaced atomically.
    name
        Scene name for the titles.
    thickness
        Masonry thickness for the deviation figure; ``None`` uses the solve's own
        (``result.parameters["loads"]["thickness"]``) when stored.
    kinds
        Figure kinds to write (see :data:`~selfsupport.figures.render.FIGURES`).
    view
        Also write the interactive ``view.html``.
    history
        Records for the history figure; ``None`` uses ``result.history``.
    dpi
        Resolution of the PNGs (8 × 6 inches).

    Returns
    -------
    ReportFiles
    """

    unknown = [k for k in kinds if k not in FIGURES]
    if unknown:
        raise InputError(f"unknown figure kind(s) {unknown}; choose from {', '.join(FIGURES)}")
    res = result if isinstance(result, SolveResult) else None
    net = res.network if res is not None else result
    if thickness is None and res is not None:
        thickness = stored_thickness(res.parameters)
    if history is None:
        history = res.history if res is not None else ()
    out = Path(directory)
    skipped: dict[str, str] = {}

    airy = directions = None
    if any(k in _NEEDS_AIRY + _NEEDS_DIRECTIONS for k in kinds) or view:
        try:
            airy = airy_of(net)
        except _SKIPPABLE as e:
            for k in _NEEDS_AIRY:
                skipped[k] = f"Airy analysis unavailable: {e}"
    if any(k in _NEEDS_DIRECTIONS for k in kinds) and airy is None:
        skipped["directions"] = skipped.get("airy", "principal directions need the Airy surface")
    elif any(k in _NEEDS_DIRECTIONS for k in kinds):
        try:
            directions = directions_of(net, airy)
        except _SKIPPABLE as e:
            skipped["directions"] = f"principal directions unavailable: {e}"

    inp = FigureInput(net, history=tuple(history), thickness=thickness, title=network_title(name, res),
                      dpi=dpi, airy=airy, directions=directions)
    figures: dict[str, Path] = {}
    for kind in kinds:
        if kind in skipped:
            continue
        try:
            png = render_png_bytes(kind, inp)
        except _SKIPPABLE as e:
            skipped[kind] = str(e)
            continue
        # outside the try: a directory that cannot be written is the caller's error, not a skip
        figures[kind] = out / f"{kind}.png"
        atomic_write_bytes(figures[kind], png)
    view_path = None
    if view:
        view_path = out / "view.html"
        write_view(view_path, net, title=inp.title, airy=airy, with_analysis=airy is not None)
    return ReportFiles(directory=out, figures=figures, view=view_path, skipped=skipped)
