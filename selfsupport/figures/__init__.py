"""Figures of thrust networks (matplotlib, headless) and a self-contained interactive HTML view
(plotly, JavaScript inlined). matplotlib and plotly are imported only when a figure is drawn.

>>> import tempfile
>>> from pathlib import Path
>>> from selfsupport import api
>>> from selfsupport.figures import FigureInput, render, write_view, write_report
>>> from selfsupport.core.shapes import make_shape
>>> result = api.solve(make_shape("dome", n_vertices=150))
>>> out = Path(tempfile.mkdtemp())
>>> render("network", FigureInput(result.network, title="dome"), out / "dome.png").name
'dome.png'
>>> write_view(out / "dome.html", result.network).layers[:2]
('reference', 'network')
>>> print(write_report(result, out / "report").markdown().splitlines()[0])
## Figures
"""
from selfsupport.figures.render import FIGURES, FigureInput, edge_forces, make_figure, render, render_png_bytes, signed_distances
from selfsupport.figures.report import REPORT_KINDS, ReportFiles, write_report
from selfsupport.figures.viewer import LAYERS, PRESETS, ViewInfo, build_view, view_html, write_view

__all__ = ["FIGURES", "FigureInput", "make_figure", "render", "render_png_bytes", "edge_forces", "signed_distances",
           "REPORT_KINDS", "ReportFiles", "write_report", "LAYERS", "PRESETS", "ViewInfo", "build_view", "view_html",
           "write_view"]
