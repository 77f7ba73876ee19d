"""Sweep reports: a Markdown summary table and PNG plots chosen in the sweep file.

Plot kinds (:data:`PLOTS`, the ``kind`` of a ``[report] plots`` entry):

* ``line`` — median of ``y`` against ``x``, one line per ``hue`` value (default ``method``),
  every run as a faint dot, one panel per ``facet`` value; e.g. ``max_rel_error`` or
  ``distance_mean`` against ``density`` or ``thickness``.
* ``time_vs_size`` — ``solve_time`` (or ``y``) against ``n_vertices``, per method, log-log.
* ``success_rate`` — share of runs that converged, per ``x`` (default ``method``), grouped
  by ``hue``.
* ``status`` — run counts per status, stacked, per ``x`` (default ``method``).

Figures are drawn on :class:`matplotlib.figure.Figure` directly (no pyplot state), so
reports can be written from any thread or process.
"""
from __future__ import annotations

import io
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from selfsupport.io.atomic import atomic_write_bytes, atomic_write_text

__all__ = ["PLOTS", "ReportFiles", "summary_table", "markdown_table", "write_report"]

#: Error statuses (kept here too so that this module does not import the dask runner).
_ERRORS = ("failed", "timeout", "crashed")
#: Columns whose plots default to a logarithmic axis.
_LOG_COLUMNS = {"max_rel_error", "distance_mean", "distance_max", "solve_time", "task_time", "n_vertices",
                "n_edges", "min_weight", "w_max", "eps", "tol", "density", "thickness"}


# ---------------------------------------------------------------------------- formatting
def _fmt(v: Any, column: str = "") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "none" if column in ("w_max", "eps", "max_iter") else "–"
    if isinstance(v, float):
        if column in ("max_rel_error", "distance_mean", "distance_max", "tol", "eps"):
            return f"{v:.1e}"
        if column.endswith("%"):
            return f"{v:.0f}"
        return f"{v:.3g}"
    return str(v)


def markdown_table(rows: list[dict[str, Any]], columns: list[str]) -> str:
    """A GitHub-flavoured Markdown table; numbers right-aligned."""
    cells = [[_fmt(r.get(c), c) for c in columns] for r in rows]
    numeric = [all(isinstance(r.get(c), (int, float)) or r.get(c) is None for r in rows) for c in columns]
    head = "| " + " | ".join(columns) + " |"
    rule = "|" + "|".join("---:" if n else ":---" for n in numeric) + "|"
    body = ["| " + " | ".join(row) + " |" for row in cells]
    return "\n".join([head, rule, *body]) + "\n"


# ---------------------------------------------------------------------------- table
def summary_table(df, by: tuple[str, ...] | list[str]) -> list[dict[str, Any]]:
    """One row per group of ``by``: runs, converged, success %, errors, median solve time and
    iterations, worst max relative error, median mean distance and worst max distance (the
    last three over the runs that produced a network)."""
    import pandas as pd

    by = list(by)
    rows = []
    for keys, g in df.groupby(by, dropna=False, sort=True):
        keys = keys if isinstance(keys, tuple) else (keys,)
        conv = int((g["status"] == "converged").sum())
        row = {c: (None if (isinstance(k, float) and math.isnan(k)) or k is pd.NA else k) for c, k in zip(by, keys)}
        row.update({
            "runs": len(g), "converged": conv, "success %": 100.0 * conv / len(g),
            "errors": int(g["status"].isin(_ERRORS).sum()),
            "median time [s]": _num(g["solve_time"].median()),
            "median iter": _num(g["iterations"].astype("float64").median()),
            "worst max rel err": _num(g["max_rel_error"].max()),
            "median dist mean": _num(g["distance_mean"].median()),
            "worst dist max": _num(g["distance_max"].max()),
        })
        rows.append(row)
    return rows


def _num(x: Any) -> float | None:
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return None if math.isnan(x) else x


# ---------------------------------------------------------------------------- plots
def _labels(series) -> list[str]:
    return [_fmt(v, series.name or "") for v in series]


def _hue_labels(df, hue) -> tuple[str, list[str]]:
    """Legend title and one label per row; ``hue`` is a column or a tuple of columns."""
    cols = (hue,) if isinstance(hue, str) else tuple(hue)
    parts = [_labels(df[c].rename(c)) for c in cols]
    return ", ".join(cols), [", ".join(vals) for vals in zip(*parts)]


def _figure(n_panels: int):
    from matplotlib.figure import Figure

    ncols = min(3, max(1, n_panels))
    nrows = math.ceil(max(1, n_panels) / ncols)
    fig = Figure(figsize=(4.6 * ncols, 3.6 * nrows), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    for ax in axes[n_panels:]:
        ax.set_visible(False)
    return fig, axes[:max(1, n_panels)]


def _panels(df, facet: str | None):
    if facet is None:
        return [(None, df)]
    return [(k, g) for k, g in df.groupby(facet, dropna=False, sort=True)]


def _log_ok(values) -> bool:
    v = values.dropna()
    return len(v) > 0 and bool((v > 0).all())


def _plot_line(df, p, path: Path) -> None:
    x, y, hue = p.x or "density", p.y or "max_rel_error", p.hue or "method"
    fig, axes = _figure(len(_panels(df, p.facet)))
    title, labels = _hue_labels(df, hue)
    colors = {lab: f"C{i % 10}" for i, lab in enumerate(sorted(set(labels)))}  # same colour in every panel
    df = df.assign(_hue=labels)
    panels = _panels(df, p.facet)
    for ax, (fv, d) in zip(axes, panels):
        for label, g in d.groupby("_hue", sort=True):
            g = g.dropna(subset=[x, y])
            if g.empty:
                continue
            ax.scatter(g[x], g[y], s=10, alpha=0.35, color=colors[label])
            med = g.groupby(x)[y].median()
            ax.plot(med.index, med.values, marker="o", label=label, color=colors[label])
        _axes(ax, d, x, y, p)
        ax.set_title(f"{p.facet} = {_fmt(fv, p.facet)}" if p.facet else (p.title or f"{y} vs {x}"), fontsize=9)
    _legend(axes, title)
    if p.facet and p.title:
        fig.suptitle(p.title)
    _save(fig, path)


def _plot_time_vs_size(df, p, path: Path) -> None:
    _plot_line(df, replace(p, x=p.x or "n_vertices", y=p.y or "solve_time", hue=p.hue or "method",
                           title=p.title or "solve time vs size"), path)


def _plot_success_rate(df, p, path: Path) -> None:

    x = p.x or "method"
    hue = p.hue
    d = df.assign(_x=_labels(df[x].rename(x)), _ok=(df["status"] == "converged").astype(float))
    cats = sorted(d["_x"].unique())
    if hue:
        htitle, hl = _hue_labels(d, hue)
        d = d.assign(_h=hl)
    hues = sorted(set(d["_h"])) if hue else [None]
    fig, (ax,) = _figure(1)
    width = 0.8 / len(hues)
    for j, h in enumerate(hues):
        g = d if h is None else d[d["_h"] == h]
        rate = g.groupby("_x")["_ok"].mean().reindex(cats)
        n = g.groupby("_x")["_ok"].size().reindex(cats).fillna(0).astype(int)
        pos = np.arange(len(cats)) + (j - (len(hues) - 1) / 2) * width
        bars = ax.bar(pos, 100 * rate.fillna(0).values, width, label=h)
        for b, k in zip(bars, n.values):
            ax.annotate(f"n={k}", (b.get_x() + b.get_width() / 2, b.get_height()), ha="center", va="bottom", fontsize=7)
    ax.set_xticks(np.arange(len(cats)), cats, rotation=20 if len(cats) > 3 else 0)
    ax.set_ylim(0, 110)
    ax.set_ylabel("converged [%]")
    ax.set_xlabel(x)
    ax.set_title(p.title or f"success rate per {x}", fontsize=9)
    _legend([ax], htitle if hue else None)
    _save(fig, path)


def _plot_status(df, p, path: Path) -> None:

    x = p.x or "method"
    d = df.assign(_x=_labels(df[x].rename(x)))
    counts = d.groupby(["_x", "status"]).size().unstack(fill_value=0)
    fig, (ax,) = _figure(1)
    bottom = np.zeros(len(counts))
    for status in counts.columns:
        ax.bar(counts.index, counts[status].values, bottom=bottom, label=status)
        bottom += counts[status].values
    ax.set_ylabel("runs")
    ax.set_xlabel(x)
    ax.set_title(p.title or f"run status per {x}", fontsize=9)
    _legend([ax], "status")
    _save(fig, path)


def _axes(ax, d, x: str, y: str, p) -> None:
    logx = p.logx if p.logx is not None else (x in _LOG_COLUMNS and _log_ok(d[x]) and d[x].nunique() > 2)
    logy = p.logy if p.logy is not None else (y in _LOG_COLUMNS and _log_ok(d[y]))
    if logx:
        ax.set_xscale("log")
    if logy:
        ax.set_yscale("log")
    ax.set_xlabel(x)
    ax.set_ylabel(y)
    ax.grid(True, which="major", alpha=0.3)


def _legend(axes, title: str | None = None) -> None:
    for ax in axes:
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, title=title, title_fontsize=7)


def _save(fig, path: Path) -> None:

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    atomic_write_bytes(path, buf.getvalue())


#: plot kind -> drawing function ``(frame, PlotSpec, png path)``
PLOTS: dict[str, Callable[[Any, Any, Path], None]] = {
    "line": _plot_line,
    "time_vs_size": _plot_time_vs_size,
    "success_rate": _plot_success_rate,
    "status": _plot_status,
}


# ---------------------------------------------------------------------------- report
@dataclass(frozen=True)
class ReportFiles:
    markdown: Path
    plots: tuple[Path, ...]
    table: str


def _plot_name(k: int, p) -> str:
    if p.file:
        return p.file if p.file.endswith(".png") else p.file + ".png"
    parts = [f"{k + 1:02d}", p.kind]
    if p.y:
        parts.append(p.y)
    if p.x:
        parts += ["vs", p.x]
    if p.facet:
        parts += ["by", p.facet]
    return "_".join(parts) + ".png"


def write_report(df, report, out_dir: str | Path, *, title: str = "Sweep", notes: list[str] | None = None) -> ReportFiles:
    """Write ``out_dir/report.md`` and ``out_dir/plots/*.png`` for the runs in ``df``.

    Parameters
    ----------
    df
        Result rows (:meth:`selfsupport.sweep.store.ResultStore.frame`).
    report
        :class:`selfsupport.sweep.spec.ReportSpec`: group-by columns and plots.
    out_dir
        Output folder.
    title, notes
        Heading and extra lines (e.g. how the sweep was run) for the Markdown file.
    """
    out_dir = Path(out_dir)
    plots: list[Path] = []
    plot_errors: list[str] = []
    if len(df):
        for k, p in enumerate(report.plots):
            path = out_dir / "plots" / _plot_name(k, p)
            d = df if p.status is None else df[df["status"].isin(p.status)]
            try:
                if d.empty:
                    raise ValueError(f"no runs with status {', '.join(p.status or ())}")
                PLOTS[p.kind](d, p, path)
                plots.append(path)
            except (KeyError, ValueError, TypeError) as e:  # a plot that cannot be drawn must not lose the report
                plot_errors.append(f"plot {k + 1} ({p.kind}): {type(e).__name__}: {e}")
    rows = summary_table(df, report.table) if len(df) else []
    cols = list(report.table) + ["runs", "converged", "success %", "errors", "median time [s]", "median iter",
                                 "worst max rel err", "median dist mean", "worst dist max"]
    table = markdown_table(rows, cols)
    counts = df["status"].value_counts().to_dict() if len(df) else {}
    lines = [f"# {title}", "", f"{len(df)} runs: " + ", ".join(f"{v} {k}" for k, v in sorted(counts.items())) + ".", ""]
    lines += [*(notes or []), ""] if notes else []
    lines += ["Distances are relative to the scene's bounding-box diagonal; errors are the paper's "
              "max relative equilibrium error; metrics are over the runs that produced a network.", "", table]
    errs = df[df["status"].isin(_ERRORS)] if len(df) else df
    if len(errs):
        lines += ["", "## Errors", ""]
        for msg, g in errs.groupby(errs["message"].fillna("").str.slice(0, 300), sort=False):
            lines.append(f"* {len(g)}× `{', '.join(sorted(set(g['status'])))}` ({', '.join(sorted(set(map(str, g['scene']))))[:120]}): {msg}")
    if plots:
        lines += ["", "## Plots", ""] + [f"![{p.stem}](plots/{p.name})" for p in plots]
    if plot_errors:
        lines += ["", "Plots that could not be drawn: " + "; ".join(plot_errors)]
    md = out_dir / "report.md"
    atomic_write_text(md, "\n".join(lines) + "\n")
    return ReportFiles(markdown=md, plots=tuple(plots), table=table)
