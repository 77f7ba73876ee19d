"""Figures of the stability studies: a network coloured by force over the masonry hull band,
and a strip of destruction stages. Built on :mod:`selfsupport.figures.render`."""
from __future__ import annotations

import io
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from selfsupport.core.result import Network
from selfsupport.figures.render import FORCE_CMAP, FigureInput, _figure, _norm, edge_forces, signed_distances
from selfsupport.io.atomic import atomic_write_bytes

__all__ = ["hull_figure", "stage_strip"]


def _force_lines(ax, net: Network, *, three_d: bool, norm=None):
    from matplotlib import colormaps

    f = edge_forces(net)
    act = net.active_edges
    cmap = colormaps[FORCE_CMAP]
    norm = norm or _norm(f[act], vmin=0.0)
    seg = net.vertices[net.edges[act]]
    order = np.argsort(f[act], kind="stable")
    if three_d:
        from mpl_toolkits.mplot3d.art3d import Line3DCollection

        ax.add_collection3d(Line3DCollection(seg[order], colors=cmap(norm(f[act][order])), linewidths=0.8))
    else:
        from matplotlib.collections import LineCollection

        ax.add_collection(LineCollection(seg[order][:, :, :2], colors=cmap(norm(f[act][order])), linewidths=0.8))
    return norm, cmap


def hull_figure(network: Network, path: str | Path, *, thickness: float, reference=None, title: str = "") -> Path:
    """Two panels: the network in 3D, edges coloured by force; and each vertex's signed distance
    to the reference surface against its plan distance from the supports' centre, over the
    hull band ±t/2 (shaded), vertices outside the band in red."""
    from matplotlib.cm import ScalarMappable


    ref = reference if reference is not None else network.reference
    inp = FigureInput(network=network, reference=ref, thickness=thickness, size=(12.0, 5.0), dpi=110)
    fig = _figure(inp)
    ax = fig.add_axes((0.0, 0.05, 0.5, 0.8), projection="3d")
    norm, cmap = _force_lines(ax, network, three_d=True)
    V = network.vertices
    lo, hi = V.min(axis=0), V.max(axis=0)
    span = float((hi - lo).max())
    mid = 0.5 * (lo + hi)
    ax.set_xlim(mid[0] - span / 2, mid[0] + span / 2)
    ax.set_ylim(mid[1] - span / 2, mid[1] + span / 2)
    ax.set_zlim(lo[2], lo[2] + span)
    ax.set_box_aspect((1, 1, 1))
    ax.set_axis_off()
    fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=ax, shrink=0.6, label="edge force [N]")
    ax2 = fig.add_axes((0.58, 0.12, 0.38, 0.7))
    d = signed_distances(V, ref)
    centre = V[network.supports].mean(axis=0) if network.supports.any() else V.mean(axis=0)
    r = np.linalg.norm(V[:, :2] - centre[:2], axis=1)
    h = 0.5 * thickness
    ax2.axhspan(-h, h, color=(0.6, 0.7, 0.9, 0.5), label=f"hull ±t/2 = ±{h:g} m")
    out = (np.abs(d) > h * 1.01) & ~network.supports
    ax2.scatter(r[~out], d[~out], s=6, c="k", label="vertex")
    if out.any():
        ax2.scatter(r[out], d[out], s=10, c="red", label=f"outside ({int(out.sum())})")
    ax2.set_xlabel("plan distance from the supports' centre [m]")
    ax2.set_ylabel("signed distance to the reference [m]")
    ax2.legend(fontsize=8, loc="best")
    fig.suptitle(title or "network over the masonry hull", fontsize=10)
    path = Path(path)

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=inp.dpi, facecolor="white")
    atomic_write_bytes(path, buf.getvalue())
    return path


def stage_strip(stages: Sequence[Any], path: str | Path, *, thickness: float) -> Path:
    """One top-view panel per destruction stage: the remaining network coloured by force (red
    vertices: outside the hull), with the stage's status."""


    k = max(len(stages), 1)
    inp = FigureInput(network=next(s.result.network for s in stages if s.result is not None),
                      size=(3.2 * k, 3.6), dpi=100)
    fig = _figure(inp)
    for j, s in enumerate(stages):
        ax = fig.add_subplot(1, k, j + 1)
        ax.set_aspect("equal")
        ax.set_axis_off()
        ax.set_title(f"stage {s.index}: {s.n_faces} faces\n{s.status}", fontsize=9)
        if s.result is None:
            continue
        net = s.result.network
        _force_lines(ax, net, three_d=False)
        out = np.asarray(s.result.parameters.get("hull", {}).get("outside_vertices", []), dtype=np.int64)
        if out.size:
            ax.scatter(net.vertices[out, 0], net.vertices[out, 1], s=5, c="red")
        ax.autoscale_view()
    path = Path(path)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=inp.dpi, facecolor="white")
    atomic_write_bytes(path, buf.getvalue())
    return path
