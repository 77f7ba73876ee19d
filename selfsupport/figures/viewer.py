"""A self-contained interactive HTML view of a thrust network (plotly, JavaScript embedded).

The file needs no network access when opened: plotly.js is inlined
(``include_plotlyjs=True``), no MathJax, no web fonts. Layers are legend groups that can
be toggled one by one (click the legend) or through the preset buttons:

* ``reference`` — the reference surface (translucent);
* ``network`` — edges, width and colour by force (colorbar in newtons); hovering an edge's
  midpoint shows its weight and force, hovering a vertex its load and equilibrium residual;
* ``supports`` — support vertices, hover shows the ground reaction;
* ``loads`` — the nodal loads as downward segments (∝ |A_i F_i|; hidden at first);
* ``Airy surface`` and ``reciprocal diagram`` — in their own panels on the right, when
  :mod:`selfsupport.analysis` can compute them for this network.

Example
-------
>>> import tempfile
>>> from pathlib import Path
>>> from selfsupport import api
>>> from selfsupport.figures.viewer import write_view
>>> from selfsupport.core.shapes import make_shape
>>> result = api.solve(make_shape("dome", n_vertices=150))
>>> out = Path(tempfile.mkdtemp())
>>> write_view(out / "dome.html", result.network, title="dome").layers[:3]
('reference', 'network', 'supports')
"""
from __future__ import annotations

import html
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from selfsupport.core.errors import InputError, SelfSupportError
from selfsupport.core.evidence import load_magnitudes, load_vectors, residuals, triangulate
from selfsupport.core.geometry import bbox_diagonal
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network
from selfsupport.figures.render import Unit, airy_of, edge_forces, reciprocal_segments
from selfsupport.io.atomic import atomic_write_text

__all__ = ["LAYERS", "PRESETS", "ViewInfo", "build_view", "view_html", "write_view"]

#: layer (legend group) -> legend label
LAYERS: dict[str, str] = {
    "reference": "reference surface",
    "network": "network (edge forces)",
    "supports": "supports",
    "loads": "loads",
    "airy": "Airy surface Φ",
    "reciprocal": "reciprocal diagram",
}
#: preset button -> layers shown
PRESETS: dict[str, tuple[str, ...]] = {
    "all layers": ("reference", "network", "supports", "loads", "airy", "reciprocal"),
    "network": ("network", "supports"),
    "network + reference": ("reference", "network", "supports"),
    "forces and loads": ("network", "supports", "loads"),
    "analysis": ("airy", "reciprocal"),
}
#: layers hidden until the user asks for them (they clutter the first view)
HIDDEN_AT_START = ("loads",)

_FORCE_BINS = 6  # plotly lines have one width per trace: edges are binned by force
_DIV_ID = "selfsupport-view"

# Page layout in pixels. plotly places the title in the top margin and the preset buttons
# in paper coordinates, and nothing stops them from overlapping: the title gets the top
# band, the buttons the band below it, the subplot titles the band below that.
_HEIGHT = 820
_MARGIN = dict(l=10, r=10, t=140, b=90)
_TITLE_TOP_PX = 8        # title block (title, subtitle, notes): from here down to about 70 px
_BUTTONS_BOTTOM_PX = 32  # bottom edge of the button row above the plotting area (subplot titles: ~25 px)
_LEGEND_TOP_PX = 52      # top of the legend below the plotting area: under the reciprocal panel's x title
#: horizontal gap between the network scene and the right-hand panels (figure fraction):
#: room for the reciprocal panel's tick labels and y title, which plotly draws to the left
#: of its axis, i.e. over the 3D scene when the gap is narrower
_PANEL_GAP = 0.1


@dataclass(frozen=True)
class ViewInfo:
    """What :func:`build_view` drew: the layers present and why any were left out."""

    layers: tuple[str, ...]
    omitted: dict[str, str]


def _lines(P: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, ...]:
    """x, y, z arrays of line segments separated by NaN gaps (plotly's line breaks).

    One more gap is appended: a per-point colour array of length exactly 3 (a single edge)
    would otherwise be taken by plotly.js for one RGB colour.
    """
    seg = np.full((len(pairs), 3, P.shape[1]), np.nan)
    seg[:, 0] = P[pairs[:, 0]]
    seg[:, 1] = P[pairs[:, 1]]
    flat = np.vstack([seg.reshape(-1, P.shape[1]), np.full((1, P.shape[1]), np.nan)])
    return tuple(flat[:, k] for k in range(P.shape[1]))


def _fmt(x: float, unit: str) -> str:
    return f"{x:.4g} {unit}" if math.isfinite(x) else "n/a"


def _camera(elev: float = 30.0, azim: float = -60.0, r: float = 2.3) -> dict:
    el, az = math.radians(elev), math.radians(azim)
    return {"eye": {"x": r * math.cos(el) * math.cos(az), "y": r * math.cos(el) * math.sin(az),
                    "z": r * math.sin(el)}}


def build_view(network: Network, *, reference: PolyMesh | None = None, title: str | None = None,
               airy: Any = None, with_analysis: bool = True) -> tuple[Any, ViewInfo]:
    """The plotly figure of ``network`` with toggleable layers.

    Parameters
    ----------
    network
        The thrust network.
    reference
        Reference surface; ``None`` uses ``network.reference`` (the layer is left out without one).
    title
        Heading of the page.
    airy
        A precomputed Airy result (``.phi``, ``.reciprocal_vertices``); ``None`` computes it
        with :mod:`selfsupport.analysis` when ``with_analysis``.
    with_analysis
        Draw the Airy surface and reciprocal diagram panels.

    Returns
    -------
    (plotly.graph_objects.Figure, ViewInfo)
    """
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    net = network
    ref = reference if reference is not None else net.reference
    omitted: dict[str, str] = {}
    if ref is None:
        omitted["reference"] = "the network file stores no reference surface"
    if with_analysis and airy is None:
        try:
            airy = airy_of(net)
        except (SelfSupportError, ValueError, np.linalg.LinAlgError) as e:
            omitted["airy"] = omitted["reciprocal"] = f"Airy analysis unavailable: {e}"
    elif not with_analysis:
        omitted["airy"] = omitted["reciprocal"] = "analysis panels switched off"

    has_airy = airy is not None and with_analysis
    if has_airy:
        fig = make_subplots(rows=2, cols=2, column_widths=[0.64, 0.36], row_heights=[0.5, 0.5],
                            specs=[[{"type": "scene", "rowspan": 2}, {"type": "scene"}], [None, {"type": "xy"}]],
                            subplot_titles=("thrust network", "Airy stress surface Φ", "reciprocal force diagram"),
                            horizontal_spacing=_PANEL_GAP, vertical_spacing=0.1)
    else:
        fig = go.Figure()

    V = net.vertices
    E = net.edges
    diag = bbox_diagonal(V)
    groups: list[str] = []

    def add(trace, group: str, **where) -> None:
        trace.legendgroup = group
        fig.add_trace(trace, **where)
        groups.append(group)

    main = {"row": 1, "col": 1} if has_airy else {}
    dense = V.shape[0] > 500  # smaller markers, or they hide the edges

    # reference surface
    if ref is not None:
        t = triangulate(ref)
        add(go.Mesh3d(x=ref.vertices[:, 0], y=ref.vertices[:, 1], z=ref.vertices[:, 2], i=t[:, 0], j=t[:, 1],
                      k=t[:, 2], color="lightsteelblue", opacity=0.3, name=LAYERS["reference"], showlegend=True,
                      hoverinfo="skip", flatshading=True), "reference", **main)

    # network edges, binned by force (one line width per trace)
    f = edge_forces(net)
    active = net.active_edges
    fa = f[active]
    fmax = float(fa.max()) if fa.size and fa.max() > 0 else 1.0
    fmin = float(fa.min()) if fa.size else 0.0
    # colours and colorbar in one unit (plotly's own ticks would read "10k" under "[N]");
    # the hover texts keep the exact values in newtons
    fu = Unit.for_magnitude(fmax, "N")
    bins = np.minimum((fa / fmax * _FORCE_BINS).astype(int), _FORCE_BINS - 1)
    idx_active = np.flatnonzero(active)
    for b in range(_FORCE_BINS):
        sel = idx_active[bins == b]
        if not sel.size:
            continue
        x, y, z = _lines(V, E[sel])
        c = np.r_[np.repeat(f[sel], 3), f[sel][-1]] / fu.scale
        # no legend entry and no colorbar here: plotly.js cannot draw a legend symbol for a
        # per-point line colour array (console warnings); the midpoint markers carry both
        add(go.Scatter3d(x=x, y=y, z=z, mode="lines", name=LAYERS["network"], showlegend=False, hoverinfo="skip",
                         line=dict(width=1.5 + 7.0 * (b + 0.5) / _FORCE_BINS, color=c, colorscale="Turbo",
                                   cmin=fmin / fu.scale, cmax=fmax / fu.scale)),
            "network", **main)
    if (~active).any():
        x, y, z = _lines(V, E[~active])
        add(go.Scatter3d(x=x, y=y, z=z, mode="lines", line=dict(width=1, color="gray"), showlegend=False,
                         hoverinfo="skip", name="support–support edges"), "network", **main)
    mid = 0.5 * (V[E[:, 0]] + V[E[:, 1]])
    w = np.asarray(net.weights, float)
    edge_text = [f"edge {k}: ({i}, {j})<br>w = {_fmt(wk, 'N/m')}<br>force |w|‖e‖ = {_fmt(fk, 'N')}"
                 for k, ((i, j), wk, fk) in enumerate(zip(E.tolist(), w.tolist(), f.tolist()))]
    add(go.Scatter3d(x=mid[:, 0], y=mid[:, 1], z=mid[:, 2], mode="markers", showlegend=True, name=LAYERS["network"],
                     marker=dict(size=1.5 if dense else 2, color=f / fu.scale, colorscale="Turbo",
                                 cmin=fmin / fu.scale, cmax=fmax / fu.scale, opacity=0.6, showscale=True,
                                 colorbar=dict(title=dict(text=fu.label("edge force")), x=0.0, xanchor="left",
                                               len=0.75, thickness=14)),
                     hovertext=edge_text, hoverinfo="text"), "network", **main)

    # vertices: load and residual on hover
    loads = np.asarray(net.loads, float)
    size = load_magnitudes(loads)
    shown = loads if loads.ndim == 1 else size  # (a signed vertical load, or the size of a 3D one)
    r = residuals(vertices=V, edges=E, weights=w, loads=loads)
    rn = np.linalg.norm(r, axis=1)
    free = ~net.supports
    ftxt = [f"vertex {i}<br>load A·F = {_fmt(shown[i], 'N')}<br>residual ‖r‖ = {_fmt(rn[i], 'N')}"
            f" (relative {rn[i] / max(size[i], 1e-300):.2e})" for i in np.flatnonzero(free)]
    add(go.Scatter3d(x=V[free, 0], y=V[free, 1], z=V[free, 2], mode="markers", showlegend=False, name="vertices",
                     marker=dict(size=1.5 if dense else 2.5, color="#333333"), hovertext=ftxt, hoverinfo="text"), "network", **main)

    # supports: the residual there is the ground reaction
    if net.supports.any():
        s = np.flatnonzero(net.supports)
        stxt = [f"support {i}<br>load A·F = {_fmt(shown[i], 'N')}<br>ground reaction = "
                f"({r[i, 0]:.4g}, {r[i, 1]:.4g}, {r[i, 2]:.4g}) N" for i in s]
        add(go.Scatter3d(x=V[s, 0], y=V[s, 1], z=V[s, 2], mode="markers", name=LAYERS["supports"], showlegend=True,
                         marker=dict(size=3 if dense else 4.5, color="black", symbol="square"), hovertext=stxt, hoverinfo="text"),
            "supports", **main)

    # loads: downward segments, length ∝ |A F| (the largest 8% of the bounding-box diagonal)
    lmax = float(size.max()) if size.size and size.max() > 0 else 1.0
    tip = V + 0.08 * diag * load_vectors(loads) / lmax
    P = np.vstack([V, tip])
    pairs = np.c_[np.arange(len(V)), len(V) + np.arange(len(V))]
    x, y, z = _lines(P, pairs)
    add(go.Scatter3d(x=x, y=y, z=z, mode="lines", name=LAYERS["loads"], showlegend=True, line=dict(color="#8b0000", width=3),
                     hoverinfo="skip"), "loads", **main)

    if has_airy:
        _airy_layers(fig, add, net, airy)

    # layout: scenes keep the data's proportions; camera as in the static figures
    scene = dict(aspectmode="data", camera=_camera(), xaxis_title="x [m]", yaxis_title="y [m]", zaxis_title="z [m]")
    # room on the left for the force colorbar; on the right the subplot grid's own column
    scene["domain"] = dict(x=[0.07, fig.layout.scene.domain.x[1] if has_airy else 1.0], y=[0.0, 1.0])
    fig.update_layout(scene=scene)
    head = title or "thrust network"
    paper_height = _HEIGHT - _MARGIN["t"] - _MARGIN["b"]
    sub = (f"{net.mesh.n_vertices} vertices, {net.mesh.n_edges} edges, max relative error "
           f"{net.max_relative_error():.2e}, forces {fmin / fu.scale:.4g} – {fmax / fu.scale:.4g} {fu.symbol}")
    notes = "; ".join(sorted({v for k, v in omitted.items() if k in ("airy", "reciprocal")}))
    fig.update_layout(
        # a real subtitle, not "<br><sup>": plotly measures it, so the anchored title is not cut off
        title=dict(text=head, subtitle=dict(text=sub + ("<br>" + notes if notes else ""), font=dict(size=12)),
                   x=0.5, xanchor="center", yref="container", y=1.0 - _TITLE_TOP_PX / _HEIGHT, yanchor="top"),
        legend=dict(itemclick="toggle", itemdoubleclick="toggleothers", groupclick="togglegroup",
                    orientation="h", x=0.5, xanchor="center", y=-_LEGEND_TOP_PX / paper_height, yanchor="top"),
        margin=_MARGIN, height=_HEIGHT, template="plotly_white",
        hoverlabel=dict(namelength=-1))
    for i, g in enumerate(groups):
        if g in HIDDEN_AT_START:
            fig.data[i].visible = "legendonly"
    present = tuple(dict.fromkeys(groups))
    buttons = []
    for label, shown in PRESETS.items():
        if not set(shown) & set(present):
            continue
        vis = [True if g in shown else "legendonly" for g in groups]
        buttons.append(dict(label=label, method="restyle", args=[{"visible": vis}]))
    # below the title (not beside it: a long title would run under them), above the subplot titles
    fig.update_layout(updatemenus=[dict(type="buttons", direction="right", x=0.0, xanchor="left",
                                        y=1.0 + _BUTTONS_BOTTOM_PX / paper_height, yanchor="bottom",
                                        buttons=buttons, showactive=False, pad=dict(r=4))])
    return fig, ViewInfo(layers=present, omitted=omitted)


def _airy_layers(fig, add, net: Network, airy: Any) -> None:
    import plotly.graph_objects as go

    V = net.vertices
    # φ drawn in one unit (kN·m for most scenes), named on the axis and in the hover
    pu = Unit.for_values(airy.phi, "N·m")
    phi = np.asarray(airy.phi, float) / pu.scale
    t = triangulate(net.mesh)
    add(go.Mesh3d(x=V[:, 0], y=V[:, 1], z=phi, i=t[:, 0], j=t[:, 1], k=t[:, 2], intensity=phi,
                  colorscale="Viridis", showscale=False, flatshading=True, name=LAYERS["airy"], showlegend=True,
                  hovertemplate=f"φ = %{{z:.4g}} {pu.symbol}<extra></extra>"), "airy", row=1, col=2)
    x, y, z = _lines(np.c_[V[:, :2], phi], net.edges)
    add(go.Scatter3d(x=x, y=y, z=z, mode="lines", line=dict(color="#222222", width=1.5), showlegend=False,
                     hoverinfo="skip", name="Φ edges"), "airy", row=1, col=2)
    # φ is a moment, x and y lengths: the Airy panel is drawn as a cube, not to scale. The
    # camera stands back far enough and the axes carry few ticks so that the tick labels
    # and axis titles stay inside this small panel instead of running into each other
    few = dict(nticks=5, tickfont=dict(size=11), title_font=dict(size=12))
    fig.update_layout(scene2=dict(aspectmode="manual", aspectratio=dict(x=1, y=1, z=0.7),
                                  camera=dict(_camera(r=1.85), center=dict(x=0, y=0, z=-0.22)),
                                  xaxis=dict(title_text="x [m]", **few), yaxis=dict(title_text="y [m]", **few),
                                  zaxis=dict(title_text=pu.label("φ"), **few)))

    seg = reciprocal_segments(net, airy)
    R = np.asarray(airy.reciprocal_vertices, float)[:, :2]
    ru = Unit.for_values(R, "N")  # the diagram's coordinates are forces: one unit on both axes
    P = seg.reshape(-1, 2) / ru.scale
    x, y = _lines(P, np.arange(len(P)).reshape(-1, 2))
    add(go.Scatter(x=x, y=y, mode="lines", line=dict(color="#1f3b73", width=1), name=LAYERS["reciprocal"],
                   showlegend=True, hoverinfo="skip"), "reciprocal", row=2, col=2)
    ef = net.mesh.edge_faces
    used = np.unique(ef[((ef >= 0).all(axis=1)) & net.active_edges])
    add(go.Scatter(x=R[used, 0] / ru.scale, y=R[used, 1] / ru.scale, mode="markers", marker=dict(size=3, color="#1f3b73"),
                   showlegend=False, name="dual vertices",
                   hovertext=[f"face {k}: ∇φ = ({R[k, 0]:.4g}, {R[k, 1]:.4g}) N" for k in used.tolist()],
                   hoverinfo="text"), "reciprocal", row=2, col=2)
    fig.update_xaxes(title_text=ru.label("∂φ/∂x"), row=2, col=2)
    fig.update_yaxes(title_text=ru.label("∂φ/∂y"), scaleanchor="x", scaleratio=1, row=2, col=2)


def view_html(fig, title: str | None = None) -> str:
    """The complete HTML page of a view, plotly.js inlined (works offline), with a ``<title>``
    (``title``, else the figure's own title without its subtitle)."""

    page = fig.to_html(include_plotlyjs=True, full_html=True, include_mathjax=False, div_id=_DIV_ID,
                       config={"displaylogo": False, "responsive": True, "scrollZoom": True})
    if title is None:
        text = fig.layout.title.text or ""
        title = re.sub(r"<[^>]*>", " ", text.split("<br>")[0]).strip() or "thrust network"
    tag = f"<title>{html.escape(title)} - selfsupport view</title>"
    return page.replace("<head>", f"<head>{tag}", 1) if "<head>" in page else tag + page


def write_view(path: str | Path, network: Network, *, reference: PolyMesh | None = None,
               title: str | None = None, airy: Any = None, with_analysis: bool = True) -> ViewInfo:
    """Write the interactive view of ``network`` to ``path`` (HTML, atomically); see :func:`build_view`."""

    path = Path(path)
    if path.suffix.lower() not in (".html", ".htm"):
        raise InputError(f"{path}: the view is an HTML page; give a file name ending in .html")
    fig, info = build_view(network, reference=reference, title=title, airy=airy, with_analysis=with_analysis)
    atomic_write_text(path, view_html(fig, title=title or "thrust network"))
    return info
