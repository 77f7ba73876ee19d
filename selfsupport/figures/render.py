"""Static figures of thrust networks (matplotlib, headless Agg; no pyplot global state).

Every figure kind is one function ``FigureInput -> matplotlib.figure.Figure`` registered in
:data:`FIGURES`:

* ``network`` — the paper's Fig. 1 style: each edge's line width ∝ its force magnitude
  ``|w_ij| ‖e_ij‖`` and coloured by it (warm = high), over the translucent reference surface,
  with a colorbar in newtons;
* ``deviation`` — the network coloured by its signed distance to the reference surface
  (positive = above); with a thickness ``t`` the colour scale spans exactly ± t/2 and the
  vertices outside the masonry hull are drawn in the over/under colours and marked;
* ``airy`` — the Airy stress surface Φ = (x, y, φ) (paper Fig. 3);
* ``reciprocal`` — the reciprocal force diagram (Fig. 5c), dual edges coloured by force;
* ``directions`` — top view with the relative principal directions (Fig. 13a);
* ``history`` — convergence of a solve per outer iteration (log scale).

Example
-------
>>> import tempfile
>>> from pathlib import Path
>>> from selfsupport import api
>>> from selfsupport.figures.render import FigureInput, render
>>> from selfsupport.core.shapes import make_shape
>>> result = api.solve(make_shape("dome", n_vertices=150))
>>> out = Path(tempfile.mkdtemp())
>>> render("network", FigureInput(result.network, title="dome"), out / "dome.png").name
'dome.png'
"""
from __future__ import annotations

import importlib
import io
import math
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from selfsupport.core.errors import InputError
from selfsupport.core.evidence import closest_points, triangulate
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network
from selfsupport.core.scene import Scene
from selfsupport.io.atomic import atomic_write_bytes
from selfsupport.methods.base import hull_excess

__all__ = ["FigureInput", "FIGURES", "HISTORY_SERIES", "Unit", "make_figure", "render", "render_png_bytes",
           "edge_forces", "signed_distances",
           "reciprocal_segments", "airy_of", "directions_of"]

#: colormap of forces: blue (low) to red (high), no white in the middle (white = background)
FORCE_CMAP = "turbo"
#: colormap of the signed distance to the reference (diverging around 0)
DEVIATION_CMAP = "RdBu_r"
#: colours of vertices above / below the masonry hull (reference ± t/2)
ABOVE_HULL, BELOW_HULL = "#ff00ff", "#00b000"


#: Most pixels of a rendered figure (50 megapixels: ~1,000 dpi at 8 x 6 in). A canvas is four
#: bytes a pixel before the PNG is encoded: an 8 x 6 in figure at ``--dpi 100000`` would need 1.9 TB.
MAX_PIXELS = 50_000_000


@dataclass(frozen=True, eq=False)
class FigureInput:
    """Everything a figure may use; a figure kind takes what it needs.

    Parameters
    ----------
    network
        The thrust network.
    history
        A solve's per-iteration records (``SolveResult.history`` or the network JSON's
        ``"history"``); needed by ``history``.
    reference
        Reference surface (z up, same units); ``None`` uses ``network.reference``.
    thickness
        Masonry thickness t [m]: ``deviation`` then shows whether the network lies within ± t/2.
    title
        Figure title (default: a summary of the network).
    elev, azim
        Camera of the 3D views [degrees].
    size, dpi
        Figure size in inches and resolution: the PNG is ``size * dpi`` pixels.
    airy, directions
        Precomputed analysis results (an ``AiryResult`` / relative principal directions);
        ``None`` computes them with :mod:`selfsupport.analysis` when needed.
    """

    network: Network
    history: Sequence[Mapping[str, Any]] = ()
    reference: PolyMesh | None = None
    thickness: float | None = None
    title: str | None = None
    elev: float = 30.0
    azim: float = -60.0
    size: tuple[float, float] = (8.0, 6.0)
    dpi: int = 150
    airy: Any = None
    directions: Any = None

    def __post_init__(self) -> None:
        if self.thickness is not None and not (math.isfinite(self.thickness) and self.thickness > 0):
            raise InputError(f"thickness must be a positive number of metres, got {self.thickness}")
        if self.dpi <= 0 or min(self.size) <= 0:
            raise InputError(f"figure size {self.size} in at {self.dpi} dpi is empty; give positive values")
        w, h = self.pixel_size
        if w * h > MAX_PIXELS:  # refused before a canvas of that size is made
            most = int(math.sqrt(MAX_PIXELS / (self.size[0] * self.size[1])))
            raise InputError(f"{self.dpi} dpi makes a {w:,} x {h:,} px figure, more than the {MAX_PIXELS:,} pixels "
                             f"a figure may have; use at most {most} dpi")

    @property
    def reference_mesh(self) -> PolyMesh | None:
        return self.reference if self.reference is not None else self.network.reference

    @property
    def pixel_size(self) -> tuple[int, int]:
        """(width, height) of the rendered PNG."""
        return int(round(self.size[0] * self.dpi)), int(round(self.size[1] * self.dpi))


# ---------------------------------------------------------------------------------- numbers
def edge_forces(network: Network) -> np.ndarray:
    """Axial force magnitude ``|w_ij| ‖e_ij‖`` of every edge [N] (3D edge length)."""
    v, e = network.vertices, network.edges
    return np.abs(np.asarray(network.weights, float)) * np.linalg.norm(v[e[:, 1]] - v[e[:, 0]], axis=1)


def signed_distances(points: np.ndarray, reference: PolyMesh) -> np.ndarray:
    """Distance of each point to the reference surface, positive above it (along its upward normal)."""
    closest, dist, normals = closest_points(points, reference)
    side = np.einsum("ij,ij->i", np.asarray(points, float) - closest, normals)
    return np.where(side < 0, -dist, dist)


def _summary_title(inp: FigureInput, what: str, detail: str | None = None) -> str:
    """``"<title> — <what>"`` over a line of mesh size and error (``detail`` appended to it):
    the figure-specific numbers go on the second line so that the first stays short."""
    net = inp.network
    head = inp.title or "thrust network"
    facts = (f"{net.mesh.n_vertices} vertices, {net.mesh.n_edges} edges, "
             f"max rel. error {net.max_relative_error():.1e}")
    return f"{head} — {what}\n{facts}" + (f"; {detail}" if detail else "")


#: smallest title font [pt] before the title is wrapped instead of shrunk further
_TITLE_MIN_FONTSIZE = 8.0
#: free space kept around the title and at the canvas edges [points]
_TITLE_PAD_PT = 4.0


def _set_title(fig, text: str, *, fontsize: float = 10.0):
    """Put ``text`` above the figure so that it fits the canvas and clears every axes.

    Fixed rectangles place the axes (see below), so nothing else would stop a long scene
    name from running off the canvas or a third title line from covering a legend: the
    title is measured with the figure's own renderer, shrunk to at most
    ``_TITLE_MIN_FONTSIZE``, then wrapped; axes whose drawn extent (labels and legends
    included) reaches into the title are lowered from the top. Deterministic: the
    measurements are Agg's, which depend only on the text, the font and the dpi.

    Parameters
    ----------
    fig
        The figure, with all its axes already added (they are measured).
    text
        The title; lines separated by ``"\\n"``.
    fontsize
        Font size [pt] when the title fits as it is.

    Returns
    -------
    matplotlib.text.Text
        The title artist.
    """

    renderer = fig.canvas.get_renderer()
    pad = _TITLE_PAD_PT * fig.dpi / 72.0
    limit = fig.bbox.width - 2 * pad
    title = fig.suptitle(text, fontsize=fontsize, y=1.0 - pad / fig.bbox.height, va="top")
    width = title.get_window_extent(renderer).width
    if width > limit:  # first shrink (up to the minimum), then wrap what still does not fit
        title.set_fontsize(max(_TITLE_MIN_FONTSIZE, fontsize * limit / width))
    for _ in range(4):
        width = title.get_window_extent(renderer).width
        if width <= limit:
            break
        lines = title.get_text().split("\n")
        longest = max(lines, key=len)
        chars = max(10, int(len(longest) * limit / width) - 1)
        title.set_text("\n".join(w for line in lines
                                 for w in (textwrap.wrap(line, chars, break_long_words=True) or [""])))
    bottom = title.get_window_extent(renderer).y0 - pad
    for ax in fig.axes:
        top = ax.get_tightbbox(renderer).y1
        if top > bottom:
            pos = ax.get_position()
            ax.set_position([pos.x0, pos.y0, pos.width, pos.height - (top - bottom) / fig.bbox.height])
    return title


# ---------------------------------------------------------------------------------- scaffolding
def _figure(inp: FigureInput):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=inp.size, dpi=inp.dpi)
    FigureCanvasAgg(fig)  # headless: the figure draws through Agg whatever the global backend is
    return fig


# Fixed rectangles (figure fractions) instead of tight layout: the PNG size is exactly
# size * dpi and the colorbar is always in the same strip on the right.
_MAIN_RECT = (0.0, 0.04, 0.81, 0.84)
_CBAR_RECT = (0.86, 0.14, 0.022, 0.66)
_MAIN_RECT_2D = (0.1, 0.1, 0.7, 0.76)


def _axes3d(fig, inp: FigureInput, points: np.ndarray, *, z_scale: float | None = None):
    """3D axes with equal aspect from the data ranges (or z stretched to ``z_scale`` of the
    largest horizontal range when z is in other units, e.g. the Airy function)."""
    ax = fig.add_axes(_MAIN_RECT, projection="3d")
    lo, hi = points.min(axis=0), points.max(axis=0)
    horizontal = max(float((hi - lo)[:2].max()), 1e-12)
    # a flat network still gets a visible z range (centred on its height)
    zmin_range = 0.02 * horizontal if z_scale is None else 1e-12
    if hi[2] - lo[2] < zmin_range:
        mid = 0.5 * (lo[2] + hi[2])
        lo[2], hi[2] = mid - 0.5 * zmin_range, mid + 0.5 * zmin_range
    lo[:2] = np.where(hi[:2] - lo[:2] > 0, lo[:2], lo[:2] - 0.5 * horizontal)
    hi[:2] = np.where(hi[:2] - lo[:2] > 0, hi[:2], hi[:2] + 0.5 * horizontal)
    rng = hi - lo
    pad = 0.02 * rng  # per axis, so that equal aspect stays exact
    for setter, a, b, p in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), lo, hi, pad):
        setter(a - p, b + p)
    ax.set_autoscale_on(False)  # the collections added later must not move the limits
    box = rng + 2 * pad
    if z_scale is not None:  # z in other units (Airy function): a fixed share of the box
        box[2] = z_scale * max(box[0], box[1])
    ax.set_box_aspect(tuple(box), zoom=1.1)
    ax.view_init(elev=inp.elev, azim=inp.azim)
    ax.computed_zorder = False  # draw in zorder: surface, then edges, then markers
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.locator_params(axis="x", nbins=5)
    ax.locator_params(axis="y", nbins=5)
    ax.locator_params(axis="z", nbins=max(2, min(5, int(6 * box[2] / box.max()) + 1)))
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_pane_color((0.96, 0.96, 0.96, 1.0))
    ax.tick_params(labelsize=7)
    return ax


#: SI prefixes a figure may use, largest first
_PREFIXES: tuple[tuple[float, str], ...] = ((1e9, "G"), (1e6, "M"), (1e3, "k"), (1.0, ""), (1e-3, "m"),
                                            (1e-6, "µ"))


@dataclass(frozen=True)
class Unit:
    """The one unit in which a figure writes a quantity: ``value_SI / scale`` in ``symbol``.

    One prefix per quantity, named once in the label, reads unambiguously (prefixes per tick,
    ``0 N`` next to ``8 kN``, or ``20000`` on an axis in N·m beside a colorbar in kN·m, do not). The data stay in SI units; only the labels are scaled.

    Attributes
    ----------
    scale
        SI value of one displayed unit (1e3 for kN).
    symbol
        The unit as written in labels (``"kN·m"``).
    """

    scale: float
    symbol: str

    @classmethod
    def for_magnitude(cls, magnitude: float, base: str) -> "Unit":
        """The largest prefix of ``base`` that keeps ``magnitude`` ≥ 1 (e.g. 52 000 N·m → kN·m)."""
        m = abs(float(magnitude)) if math.isfinite(magnitude) else 0.0
        if m == 0.0:
            return cls(1.0, base)
        for scale, prefix in _PREFIXES:
            if m >= scale:
                return cls(scale, prefix + base)
        return cls(_PREFIXES[-1][0], _PREFIXES[-1][1] + base)

    @classmethod
    def for_values(cls, values: Any, base: str) -> "Unit":
        """:meth:`for_magnitude` of the largest finite ``|value|``."""
        v = np.abs(np.asarray(values, float))
        v = v[np.isfinite(v)]
        return cls.for_magnitude(float(v.max()) if v.size else 0.0, base)

    def label(self, text: str) -> str:
        """``"text [symbol]"``."""
        return f"{text} [{self.symbol}]"

    def formatter(self):
        """A tick formatter writing ``value / scale`` as a plain number (no prefix, no unit)."""
        from matplotlib.ticker import FuncFormatter

        def fmt(x: float, _pos: Any = None) -> str:
            v = float(f"{x / self.scale:.6g}")  # 39.99999999 -> 40, and no "-0"
            return f"{v + 0.0:g}".replace("-", "\N{MINUS SIGN}")

        return FuncFormatter(fmt)


def _colorbar(fig, mappable, label: str, *, unit: Unit | None = None, extend: str = "neither"):
    cax = fig.add_axes(_CBAR_RECT)
    cb = fig.colorbar(mappable, cax=cax, extend=extend)
    if unit is not None:
        cb.formatter = unit.formatter()
        cb.update_ticks()
        label = unit.label(label)
    cb.set_label(label)
    cax.tick_params(labelsize=8)
    return cb


def _norm(values: np.ndarray, vmin: float | None = None, vmax: float | None = None):
    from matplotlib.colors import Normalize

    lo = float(np.min(values)) if vmin is None else vmin
    hi = float(np.max(values)) if vmax is None else vmax
    if not hi > lo:  # constant data: a non-degenerate scale around it
        d = max(abs(hi), 1.0) * 1e-6
        lo, hi = lo - d, hi + d
    return Normalize(lo, hi)


def _reference_surface(ax, mesh: PolyMesh, *, alpha: float = 0.13) -> None:
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    tris = mesh.vertices[triangulate(mesh)]
    ax.add_collection3d(Poly3DCollection(tris, facecolors=(0.45, 0.5, 0.6, alpha), edgecolors="none", zorder=1))


def _supports(ax, net: Network) -> None:
    s = net.supports
    if s.any():
        p = net.vertices[s]
        size = float(np.clip(600.0 / len(p), 2.0, 10.0))  # many supports: smaller marks
        ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=size, c="black", marker="s", depthshade=False, zorder=4,
                   label="supports")


def _line_widths(forces: np.ndarray, n_edges: int) -> np.ndarray:
    """Width ∝ force; the widest line is thinner on dense meshes so they stay readable."""
    wmax = float(np.clip(3.6 * math.sqrt(800.0 / max(n_edges, 1)), 1.4, 4.5))
    fmax = float(forces.max()) if forces.size and forces.max() > 0 else 1.0
    return 0.25 + (wmax - 0.25) * forces / fmax


# ---------------------------------------------------------------------------------- kinds
def figure_network(inp: FigureInput):
    """Fig. 1 style: edge width ∝ force and coloured by it, translucent reference, colorbar [N]."""
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    net = inp.network
    fig = _figure(inp)
    ref = inp.reference_mesh
    pts = net.vertices if ref is None else np.vstack([net.vertices, ref.vertices])
    ax = _axes3d(fig, inp, pts)
    if ref is not None:
        _reference_surface(ax, ref)
    active = net.active_edges
    f = edge_forces(net)
    seg = net.vertices[net.edges]
    if (~active).any():  # support-support edges carry nothing: thin grey
        ax.add_collection3d(Line3DCollection(seg[~active], colors="0.55", linewidths=0.4, zorder=2))
    fa = f[active]
    norm = _norm(fa, vmin=0.0 if fa.size == 0 else None)
    cmap = colormaps[FORCE_CMAP]
    order = np.argsort(fa, kind="stable")  # strong edges drawn last, on top
    ax.add_collection3d(Line3DCollection(seg[active][order], colors=cmap(norm(fa[order])),
                                         linewidths=_line_widths(fa[order], len(fa)), zorder=3,
                                         capstyle="round"))
    _supports(ax, net)
    _colorbar(fig, ScalarMappable(norm=norm, cmap=cmap), "edge force |w| ‖e‖",
              unit=Unit.for_magnitude(max(abs(norm.vmin), abs(norm.vmax)), "N"))
    _set_title(fig, _summary_title(inp, "edge forces"))
    return fig


def figure_deviation(inp: FigureInput):
    """Signed distance to the reference; with t, the colour scale is the masonry hull ± t/2."""
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    net = inp.network
    ref = inp.reference_mesh
    if ref is None:
        raise InputError("the deviation figure needs a reference surface: pass --reference SCENE "
                         "or use a network file that stores reference_vertices")
    d = signed_distances(net.vertices, ref)
    fig = _figure(inp)
    ax = _axes3d(fig, inp, np.vstack([net.vertices, ref.vertices]))
    _reference_surface(ax, ref, alpha=0.1)
    cmap = colormaps[DEVIATION_CMAP]
    if inp.thickness is not None:

        half = 0.5 * inp.thickness
        cmap = cmap.with_extremes(over=ABOVE_HULL, under=BELOW_HULL)
        # the hull's one definition (tolerance included), as the solve's record and warning count it
        rep = hull_excess(Scene(mesh=ref, supports=net.supports), net, inp.thickness)
        outside = ~np.asarray(rep["inside"])
        extend = "both"
        detail = f"{rep['outside']} of {rep['free']} free vertices outside ± t/2 = ± {half:.3g} m"
    else:
        half = max(float(np.abs(d).max()), 1e-12)
        outside = np.zeros(len(d), dtype=bool)
        extend = "neither"
        detail = f"max distance {half:.3g} m"
    norm = _norm(d, -half, half)
    e = net.edges
    de = 0.5 * (d[e[:, 0]] + d[e[:, 1]])
    ax.add_collection3d(Line3DCollection(net.vertices[e], colors=cmap(norm(de)), linewidths=1.0, zorder=3))
    p = net.vertices
    ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=float(np.clip(1200.0 / len(p), 2.0, 8.0)), c=cmap(norm(d)),
               depthshade=False, zorder=4, edgecolors="none")
    if outside.any():
        q = p[outside]
        ax.scatter(q[:, 0], q[:, 1], q[:, 2], s=float(np.clip(3000.0 / len(q), 5.0, 28.0)), marker="x", c="black",
                   linewidths=0.6, depthshade=False, zorder=5, gid="outside-hull")
    _colorbar(fig, ScalarMappable(norm=norm, cmap=cmap), "signed distance to reference (+ above)",
              unit=Unit.for_magnitude(half, "m"), extend=extend)
    _set_title(fig, _summary_title(inp, "distance to reference", detail))
    return fig


def reaction_arrows(network: Network) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The top view of the support reactions: each support's plan position ``(k, 2)``, its
    horizontal reaction ``(k, 2)`` [N] and its vertical reaction ``(k,)`` [N]
    (:meth:`~selfsupport.core.result.Network.support_reactions`: the ground's force on the network)."""
    R = network.support_reactions()
    return network.vertices[network.supports][:, :2], R[:, :2], R[:, 2]


def figure_reactions(inp: FigureInput):
    """Top view: the network in grey and, at each support, an arrow of its horizontal reaction
    (length ∝ force; the ground pushing on the vault, so inward where the vault thrusts outward),
    the support dot coloured by the vertical reaction; the totals in the title."""
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.collections import LineCollection

    net = inp.network
    if not net.supports.any():
        raise InputError("the reactions figure needs supports; the network has none")
    P, H, Z = reaction_arrows(net)
    fig = _figure(inp)
    ax = fig.add_axes(_MAIN_RECT_2D)
    ax.add_collection(LineCollection(net.vertices[net.edges][:, :, :2], colors="0.75", linewidths=0.5))
    span = float(np.ptp(net.vertices[:, :2], axis=0).max()) or 1.0
    h = np.linalg.norm(H, axis=1)
    scale = 0.15 * span / max(float(h.max()), 1e-300)  # the largest arrow 15% of the plan
    unit = Unit.for_magnitude(max(float(np.abs(Z).max()), float(h.max())), "N")
    ax.quiver(P[:, 0], P[:, 1], H[:, 0] * scale, H[:, 1] * scale, angles="xy", scale_units="xy", scale=1.0,
              color="tab:red", width=0.004, zorder=4, label="horizontal reaction")
    cmap = colormaps["viridis"]
    norm = _norm(Z)
    ax.scatter(P[:, 0], P[:, 1], s=float(np.clip(600.0 / len(P), 4.0, 24.0)), c=cmap(norm(Z)), zorder=5,
               edgecolors="black", linewidths=0.3, label="support (vertical reaction)")
    # the arrows reach beyond the plan: the limits take them in
    ends = np.vstack([net.vertices[:, :2], P + H * scale])
    ax.update_datalim(ends)
    _equal_2d(ax)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.tick_params(labelsize=8)
    ax.legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=2, fontsize=7, frameon=False)
    _colorbar(fig, ScalarMappable(norm=norm, cmap=cmap), "vertical reaction", unit=unit)
    s = net.reaction_summary()
    detail = (f"vertical {s['vertical'] / unit.scale:.4g} {unit.symbol}, max horizontal "
              f"{s['max_horizontal'] / unit.scale:.4g} {unit.symbol} (longest arrow), thrust "
              f"{s['thrust'] / unit.scale:.4g} {unit.symbol}")
    _set_title(fig, _summary_title(inp, "support reactions (top view)", detail))
    return fig


# ---------------------------------------------------------------------------------- analysis
def _analysis(name: str):
    """``selfsupport.analysis.<name>``, imported lazily (figures of forces do not need it)."""

    try:
        return importlib.import_module(f"selfsupport.analysis.{name}")
    except ImportError as e:
        raise InputError(f"this figure needs selfsupport.analysis.{name}, which cannot be imported ({e}); "
                         "draw the network, deviation or history figures instead") from None


def airy_of(network: Network):
    """The Airy stress surface of ``network`` (``.phi`` per vertex, ``.reciprocal_vertices`` per face)."""
    return _analysis("airy").airy(network)


def directions_of(network: Network, airy: Any = None):
    """Curvatures of ``network`` relative to its Airy surface, with the relative principal
    directions (``.principal_directions`` ``(n, 2, 2)``, ``[i, :, k]`` the direction of κ_k,
    κ₁ ≤ κ₂; ``NaN`` where Φ is not strictly convex)."""
    return _analysis("curvature").curvatures(network, airy, directions=True)


def _airy_of(inp: FigureInput):
    if inp.airy is not None:
        return inp.airy
    return airy_of(inp.network)


def figure_airy(inp: FigureInput):
    """The Airy stress surface Φ over the top view: planar faces, shaded, coloured by φ."""
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    net = inp.network
    a = _airy_of(inp)
    phi = np.asarray(a.phi, float)
    P = np.c_[net.vertices[:, :2], phi]
    fig = _figure(inp)
    ax = _axes3d(fig, inp, P, z_scale=0.55)
    # φ on the vertical axis and on the colorbar in the same unit, chosen once
    unit = Unit.for_values(phi, "N·m")
    ax.set_zlabel(unit.label("φ"))
    ax.zaxis.set_major_formatter(unit.formatter())
    tri = triangulate(net.mesh)
    cmap = colormaps["viridis"]
    norm = _norm(phi)
    # Lambert shading in the axes' display proportions, so the facets read as a polyhedron
    lo, hi = P.min(axis=0), P.max(axis=0)
    box = np.asarray(ax.get_box_aspect(), float)
    Q = (P - lo) / np.maximum(hi - lo, 1e-300) * box
    n = np.cross(Q[tri[:, 1]] - Q[tri[:, 0]], Q[tri[:, 2]] - Q[tri[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    light = np.array([-0.4, -0.5, 0.77])
    shade = 0.55 + 0.45 * np.abs(n @ (light / np.linalg.norm(light)))
    col = cmap(norm(phi[tri].mean(axis=1)))
    col[:, :3] *= shade[:, None]
    ax.add_collection3d(Poly3DCollection(P[tri], facecolors=col, edgecolors="none", zorder=1))
    ax.add_collection3d(Line3DCollection(P[net.edges], colors="0.15", linewidths=0.35, zorder=2))
    _colorbar(fig, ScalarMappable(norm=norm, cmap=cmap), "Airy stress function φ", unit=unit)
    # φ has its own units (force × length): the vertical axis is scaled to a fixed share of the box
    fig.text(0.01, 0.01, f"units: x, y in m; φ in {unit.symbol} (vertical axis not to scale)",
             fontsize=7, color="0.3", ha="left", va="bottom")
    _set_title(fig, _summary_title(inp, "Airy stress surface Φ"))
    return fig


def reciprocal_segments(network: Network, airy: Any) -> np.ndarray:
    """``(k, 2, 2)`` dual edges of the interior edges that carry a weight (not support–support).

    Dual edge of edge ij: from the vertex of the face on one side to that of the face on the
    other. Where the analysis cut the dual graph (around holes and support patches Φ has a
    period, so the two face planes belong to different sheets) it is drawn from the first
    face along the prescribed jump ``airy.jumps`` instead.
    """
    R = np.asarray(airy.reciprocal_vertices, float)[:, :2]
    ef = network.mesh.edge_faces
    keep = (ef >= 0).all(axis=1) & network.active_edges
    a, b = R[ef[:, 0]], R[ef[:, 1]].copy()
    cut = np.zeros(len(ef), dtype=bool)
    cut[np.asarray(getattr(airy, "cut_edges", ()), dtype=np.int64)] = True
    jumps = getattr(airy, "jumps", None)
    if jumps is not None and cut.any():
        b[cut] = a[cut] - np.asarray(jumps, float)[cut, :2]  # ∇Φ_R = ∇Φ_L − jump
    return np.stack([a[keep], b[keep]], axis=1)


def figure_reciprocal(inp: FigureInput):
    """Reciprocal force diagram: one vertex per face, dual edges across interior edges."""
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.collections import LineCollection

    net = inp.network
    a = _airy_of(inp)
    seg = reciprocal_segments(net, a)
    R = np.unique(seg.reshape(-1, 2), axis=0)  # the dual vertices that the diagram uses
    # a dual edge is w_ij J e'_ij: its length is the horizontal force of the primal edge
    hforce = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)
    fig = _figure(inp)
    ax = fig.add_axes(_MAIN_RECT_2D)
    cmap = colormaps[FORCE_CMAP]
    norm = _norm(hforce, vmin=0.0)
    order = np.argsort(hforce, kind="stable")
    ax.add_collection(LineCollection(seg[order], colors=cmap(norm(hforce[order])),
                                     linewidths=0.5 + 1.3 * hforce[order] / max(hforce.max(), 1e-300)))
    ax.scatter(R[:, 0], R[:, 1], s=2.0 if len(R) < 500 else 0.7, c="0.2", zorder=3, edgecolors="none")
    if not seg.size:
        raise InputError("the network has no interior edge carrying a weight: its reciprocal diagram is empty")
    _equal_2d(ax)
    # coordinates and dual edge lengths are both forces: one unit for the whole figure
    unit = Unit.for_values(np.r_[R.ravel(), hforce], "N")
    ax.set_xlabel(unit.label("∂φ/∂x"))
    ax.set_ylabel(unit.label("∂φ/∂y"))
    ax.xaxis.set_major_formatter(unit.formatter())
    ax.yaxis.set_major_formatter(unit.formatter())
    ax.tick_params(labelsize=8)
    _colorbar(fig, ScalarMappable(norm=norm, cmap=cmap), "horizontal force |w| ‖e′‖", unit=unit)
    _set_title(fig, _summary_title(inp, "reciprocal force diagram", "dual edge length = horizontal force"))
    return fig


def _directions_of(inp: FigureInput):
    if inp.directions is not None:
        return inp.directions
    return directions_of(inp.network, inp.airy)


def figure_directions(inp: FigureInput):
    """Top view with the relative principal directions at every free vertex (Fig. 13a)."""
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.collections import LineCollection, PolyCollection

    net = inp.network
    dirs = _directions_of(inp)
    v = net.vertices
    mesh = net.mesh
    fig = _figure(inp)
    ax = fig.add_axes(_MAIN_RECT_2D)
    # faces coloured by height: the top view alone would hide the shape
    cmap = colormaps["Greys"]
    norm = _norm(v[:, 2])
    tri = triangulate(mesh)
    ax.add_collection(PolyCollection(v[tri][:, :, :2], facecolors=cmap(0.15 + 0.45 * norm(v[tri][:, :, 2].mean(1))),
                                     edgecolors="none", zorder=0))
    ax.add_collection(LineCollection(v[mesh.edges][:, :, :2], colors="0.6", linewidths=0.3, zorder=1))
    h = 0.35 * float(np.median(np.linalg.norm(v[mesh.edges[:, 1], :2] - v[mesh.edges[:, 0], :2], axis=1)))
    D = np.asarray(dirs.principal_directions, float)
    at = np.flatnonzero(~net.supports & np.isfinite(D).all(axis=(1, 2)))
    if not at.size:
        raise InputError("no vertex has real relative principal directions (Φ is nowhere strictly convex)")
    p = v[at, :2]
    for k, color, label in ((0, "#1f5fbf", "direction of κ₁ (smaller)"), (1, "#c0392b", "direction of κ₂ (larger)")):
        d = D[at, :, k]
        d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
        ax.add_collection(LineCollection(np.stack([p - h * d, p + h * d], axis=1), colors=color, linewidths=0.9,
                                         zorder=2, label=label))
    ax.scatter(v[net.supports, 0], v[net.supports, 1], s=6, c="black", marker="s", zorder=3, label="supports")
    _equal_2d(ax)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.tick_params(labelsize=8)
    # above the axes: inside, it would hide part of the plan
    ax.legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=3, fontsize=7, frameon=False)
    _colorbar(fig, ScalarMappable(norm=norm, cmap=_truncated(cmap, 0.15, 0.6)), "height z (shading)",
              unit=Unit(1.0, "m"))  # heights in the unit of the x and y axes
    _set_title(fig, _summary_title(inp, "relative principal directions (top view)"))
    return fig


def _equal_2d(ax) -> None:
    """Equal aspect around the data (limits follow the data, the axes box stays put)."""
    ax.set_aspect("equal", adjustable="datalim")
    ax.margins(0.03)
    ax.autoscale_view()


def _truncated(cmap, lo: float, hi: float):
    from matplotlib.colors import ListedColormap

    return ListedColormap(cmap(np.linspace(lo, hi, 256)))


#: history key -> (legend label, panel); both the staggered and the simultaneous records
HISTORY_SERIES: dict[str, tuple[str, str]] = {
    "E": ("fit error E (relative)", "error"),
    "max_rel_error": ("max relative error", "error"),
    "max_relative_error": ("max relative error", "error"),
    "objective": ("objective", "error"),
    "load_change": ("load change", "error"),
    "alpha": ("α (reference penalty)", "penalty"),
    "beta": ("β (proximal penalty)", "penalty"),
}
_PANEL_LABELS = {"error": "error", "penalty": "penalty weight"}
_FINAL_STAGES = ("polish", "refine")
#: record key that counts the records -> x-axis label (staggered: outer iterations; IPOPT: load rounds)
_HISTORY_COUNTERS = {"iteration": "outer iteration", "round": "load round"}


def figure_history(inp: FigureInput):
    """Convergence of a solve: errors (top) and penalties (bottom) per iteration, log scale."""
    hist = [dict(r) for r in inp.history]
    if not hist:
        raise InputError("the history figure needs a solve history: use a network written by `selfsupport solve` "
                         "(it stores the \"history\" key) or pass SolveResult.history")
    present = [k for k in HISTORY_SERIES if any(_positive_number(r.get(k)) for r in hist)]
    if not present:
        raise InputError(f"the history records have none of the plotted keys ({', '.join(HISTORY_SERIES)}); "
                         "nothing to draw")
    panels = [p for p in dict.fromkeys(HISTORY_SERIES[k][1] for k in present)]
    fig = _figure(inp)
    x = np.arange(1, len(hist) + 1)
    final = [i for i, r in enumerate(hist) if r.get("iteration") in _FINAL_STAGES or r.get("stage") in _FINAL_STAGES]
    top = 0.86
    height = (top - 0.1) / len(panels)
    axes = {}
    for k, panel in enumerate(panels):
        rect = (0.11, top - (k + 1) * height + 0.05, 0.62, height - 0.07)
        ax = fig.add_axes(rect, sharex=axes[panels[0]] if axes else None)
        ax.set_yscale("log")
        ax.set_ylabel(_PANEL_LABELS[panel])
        ax.grid(True, which="major", alpha=0.3)
        ax.tick_params(labelsize=8)
        axes[panel] = ax
    for key in present:
        label, panel = HISTORY_SERIES[key]
        y = np.array([float(r[key]) if _positive_number(r.get(key)) else np.nan for r in hist])
        axes[panel].plot(x, y, marker="o", markersize=3, linewidth=1.2, label=label)
    rejected = [i for i, r in enumerate(hist) if r.get("accepted") is False]
    if rejected and "E" in present:
        y = [float(hist[i]["E"]) for i in rejected]
        axes["error"].scatter(x[rejected], y, s=40, facecolors="none", edgecolors="red", zorder=4,
                              label="position step rejected")
    for ax in axes.values():
        for i in final:
            ax.axvline(x[i], color="0.5", linestyle=":", linewidth=1)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    last = axes[panels[-1]]
    counter = next((label for key, label in _HISTORY_COUNTERS.items() if key in hist[0]), "record")
    stages = " / ".join(dict.fromkeys("refinement" if (r.get("iteration") or r.get("stage")) == "refine"
                                      else "final polish" for r in (hist[i] for i in final)))
    last.set_xlabel(counter + (f" (dotted: {stages})" if final else ""))
    last.xaxis.get_major_locator().set_params(integer=True)
    for ax in list(axes.values())[:-1]:
        ax.tick_params(labelbottom=False)
    _set_title(fig, _summary_title(inp, f"convergence ({len(hist)} records)"))
    return fig


def _positive_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x > 0


#: figure kind -> function
FIGURES: dict[str, Callable[[FigureInput], Any]] = {
    "network": figure_network,
    "deviation": figure_deviation,
    "airy": figure_airy,
    "reciprocal": figure_reciprocal,
    "directions": figure_directions,
    "history": figure_history,
    "reactions": figure_reactions,
}


def make_figure(kind: str, inp: FigureInput):
    """The matplotlib ``Figure`` of ``kind`` (see :data:`FIGURES`).

    Raises
    ------
    InputError
        Unknown kind, or the input lacks what the kind needs (reference, history, ...).
    """
    try:
        fn = FIGURES[kind]
    except KeyError:
        raise InputError(f"unknown figure kind {kind!r}; choose one of {', '.join(FIGURES)}") from None
    return fn(inp)


def render_png_bytes(kind: str, inp: FigureInput) -> bytes:
    """The PNG of ``kind``, exactly ``inp.pixel_size`` pixels."""
    fig = make_figure(kind, inp)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=inp.dpi, facecolor="white")
    return buf.getvalue()


def render(kind: str, inp: FigureInput, path: str | Path) -> Path:
    """Render ``kind`` to the PNG file ``path`` (written atomically) and return the path."""

    path = Path(path)
    if path.suffix.lower() != ".png":
        raise InputError(f"{path}: figures are written as PNG; give a file name ending in .png")
    atomic_write_bytes(path, render_png_bytes(kind, inp))
    return path
