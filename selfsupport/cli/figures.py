"""``selfsupport render`` and ``selfsupport view`` (picked up by :func:`selfsupport.cli.discover_commands`).

::

    selfsupport render NET.json --out FIG.png [--what network|deviation|airy|reciprocal|directions|history]
                       [--reference SCENE] [--thickness T]
    selfsupport view NET.json --out VIEW.html [--reference SCENE]

Heavy libraries (matplotlib, plotly) are imported inside ``run``, not at import time.
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from selfsupport.cli.common import Command, _positive_float, _positive_int, load_scene, number_in
from selfsupport.core.errors import InputError
from selfsupport.figures.render import FigureInput, render
from selfsupport.figures.report import stored_thickness
from selfsupport.figures.viewer import write_view
from selfsupport.io import read_mesh, read_network
from selfsupport.io.meshfiles import Source
from selfsupport.io.network_json import load_json
from selfsupport.io.safety import check_outputs

__all__ = ["COMMANDS", "add_render_arguments", "run_render", "add_view_arguments", "run_view", "load_document"]

#: figure kinds offered by ``--what`` (kept here so that ``--help`` does not import matplotlib;
#: a test checks it equals ``selfsupport.figures.render.FIGURES``)
FIGURE_KINDS = ("network", "deviation", "airy", "reciprocal", "directions", "history", "reactions")


def load_document(path: str | Path) -> tuple[Any, dict[str, Any]]:
    """A network file as ``(Network, the JSON document)`` (the document holds history, parameters …)."""
    return read_network(path), load_json(Source(path))


def _reference(spec: str | None, up: str | None):
    """The reference mesh from ``--reference`` (a scene/mesh file or ``shape:NAME[:N]``)."""
    if spec is None:
        if up is not None:
            raise InputError("--up applies to the --reference file; give --reference too")
        return None
    if spec.startswith("shape:"):
        return load_scene(spec, up=up).mesh
    if not Path(spec).exists():
        raise InputError(f"--reference {spec}: no such file; give the scene or mesh file the network was solved from")
    return read_mesh(spec, up=up)


def _inputs(args: argparse.Namespace) -> list[tuple[str, str | None]]:
    ref = args.reference if args.reference and not args.reference.startswith("shape:") else None
    return [("NET.json", args.network), ("--reference", ref)]


def _title(doc: dict[str, Any], path: str, given: str | None) -> str:
    if given:
        return given
    scene = doc.get("scene")
    name = scene.get("name") if isinstance(scene, dict) else None
    head = name if isinstance(name, str) and name else Path(path).stem
    status, method = doc.get("status"), doc.get("method")
    return f"{head} ({method}, {status})" if isinstance(status, str) and isinstance(method, str) else head


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("network", metavar="NET.json", help="network file written by 'selfsupport solve'")
    p.add_argument("--reference", metavar="SCENE", default=None,
                   help="reference surface (scene/mesh file or shape:NAME[:N]); default: the one stored "
                        "in the network file")
    p.add_argument("--up", default=None, metavar="AXIS", help="vertical axis of the --reference file")
    p.add_argument("--title", default=None, help="figure title (default: scene name, method and status)")


# ------------------------------------------------------------------------------------ render
def add_render_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``selfsupport render``."""
    _common(p)
    p.add_argument("--out", "-o", required=True, metavar="FIG.png", help="PNG file to write")
    p.add_argument("--what", choices=FIGURE_KINDS, default="network",
                   help="figure kind (default network): edge forces; distance to the reference; Airy stress "
                        "surface; reciprocal diagram; relative principal directions; convergence history")
    p.add_argument("--thickness", type=_positive_float, default=None, metavar="T",
                   help="masonry thickness [m] for --what deviation: show whether the network lies within "
                        "± T/2 of the reference (default: the thickness the solve used, if stored)")
    p.add_argument("--dpi", type=_positive_int, default=150, help="resolution (the figure is 8 x 6 inches)")
    p.add_argument("--elev", type=number_in("[-90, 90]"), default=30.0,
                   help="camera elevation of 3D views [degrees, -90 .. 90] (default 30)")
    p.add_argument("--azim", type=number_in("[-360, 360]"), default=-60.0,
                   help="camera azimuth of 3D views [degrees, -360 .. 360] (default -60)")


def run_render(args: argparse.Namespace) -> int:
    """Render one figure of a network file; prints what was written."""
    check_outputs([("--out", args.out)], _inputs(args))
    net, doc = load_document(args.network)
    thickness = args.thickness
    if thickness is None and isinstance(doc.get("parameters"), dict):
        thickness = stored_thickness(doc["parameters"])
    history = doc.get("history") if isinstance(doc.get("history"), list) else ()
    history = tuple(r for r in history if isinstance(r, dict))
    inp = FigureInput(net, history=history, reference=_reference(args.reference, args.up),
                      thickness=thickness, title=_title(doc, args.network, args.title), elev=args.elev,
                      azim=args.azim, dpi=args.dpi)
    path = render(args.what, inp, args.out)
    w, h = inp.pixel_size
    print(f"wrote {path} ({args.what} figure, {w} x {h} px)")
    return 0


# -------------------------------------------------------------------------------------- view
def add_view_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``selfsupport view``."""
    _common(p)
    p.add_argument("--out", "-o", required=True, metavar="VIEW.html", help="HTML file to write (self-contained)")
    p.add_argument("--no-analysis", action="store_true", help="leave out the Airy surface and reciprocal diagram")


def run_view(args: argparse.Namespace) -> int:
    """Write the interactive HTML view of a network file."""
    check_outputs([("--out", args.out)], _inputs(args))
    net, doc = load_document(args.network)
    info = write_view(args.out, net, reference=_reference(args.reference, args.up),
                      title=_title(doc, args.network, args.title), with_analysis=not args.no_analysis)
    size = Path(args.out).stat().st_size / 1e6
    print(f"wrote {args.out} ({size:.1f} MB, works offline; layers: {', '.join(info.layers)})")
    for layer, why in sorted(info.omitted.items()):
        print(f"  {layer} left out: {why}")
    return 0


COMMANDS: dict[str, Command] = {
    "render": Command("draw a figure of a network file as PNG (forces, deviation, Airy, reciprocal, directions, "
                      "history)", add_render_arguments, run_render),
    "view": Command("write a self-contained interactive HTML view of a network file", add_view_arguments, run_view),
}
