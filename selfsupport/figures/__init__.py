"""Figures of thrust networks (matplotlib, headless) and a self-contained interactive HTML view
(plotly, JavaScript inlined). matplotlib and plotly are imported only when a figure is drawn.

>>> from selfsupport.figures import FigureInput, render, write_view, write_report
>>> render("network", FigureInput(result.network, title="dome"), "dome.png")   # doctest: +SKIP
>>> write_view("dome.html", result.network)                                    # doctest: +SKIP
>>> write_report(result, "out/").markdown()                                    # doctest: +SKIP
"""
from .render import FIGURES, FigureInput, edge_forces, make_figure, render, render_png_bytes, signed_distances
from .report import REPORT_KINDS, ReportFiles, write_report
from .viewer import LAYERS, PRESETS, ViewInfo, build_view, view_html, write_view

__all__ = ["FIGURES", "FigureInput", "make_figure", "render", "render_png_bytes", "edge_forces", "signed_distances",
           "REPORT_KINDS", "ReportFiles", "write_report", "LAYERS", "PRESETS", "ViewInfo", "build_view", "view_html",
           "write_view"]
