"""``selfsupport design`` (picked up by :func:`selfsupport.cli.discover_commands`).

::

    selfsupport design SCENE [--port P] [--no-browser] [--up AXIS] [--supports FILE]
                             [--density RHO] [--thickness T]

Starts the interactive design tool (:mod:`selfsupport.app.server`) on 127.0.0.1 and prints
one line, the page's URL with its token (``http://127.0.0.1:PORT/?token=...``; a new token at
every start). ``SCENE`` is a scene or mesh file, ``shape:NAME[:N]``, or an edit script
(``.toml``, as written by the page's "edit script" button or read by ``selfsupport edit``):
its edits are applied, so a saved session goes on where it stopped. Files the page saves go
below the current folder. Stop with Ctrl+C.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

from selfsupport.app.server import DesignServer, bind_loopback, create_app, new_token, serve
from selfsupport.app.session import SOLVE_DEFAULTS, EditLog
from selfsupport.cli.common import EXIT_CODES, Command, load_scene, number_in, positive_float
from selfsupport.core.errors import InputError
from selfsupport.design.edits import Design
from selfsupport.design.script import EditScript, _start_scene

__all__ = ["COMMANDS", "add_design_arguments", "run_design", "open_session"]


def add_design_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``selfsupport design``."""
    p.add_argument("scene", metavar="SCENE", help="scene/mesh file, shape:NAME[:N], or an edit script (.toml)")
    p.add_argument("--port", type=number_in("[0, 65535]", integer=True), default=0, metavar="P", help="port on 127.0.0.1 (default: a free one)")
    p.add_argument("--no-browser", action="store_true", help="print the URL only; do not open a browser")
    p.add_argument("--up", default=None, metavar="AXIS", help="the scene file's vertical axis (default: the format's)")
    p.add_argument("--supports", default=None, metavar="boundary|FILE", help="supports for files without pins")
    p.add_argument("--density", type=positive_float, default=None, metavar="RHO", help="density [kg/m³] (default 2000)")
    p.add_argument("--thickness", type=positive_float, default=None, metavar="T", help="thickness [m] (default 0.1)")


def open_session(spec: str, *, up: str | None = None, supports: str | None = None, density: float | None = None,
                 thickness: float | None = None):
    """The :class:`~selfsupport.app.session.EditLog` of a ``SCENE`` argument (see the module docstring)."""
    if spec.endswith(".toml") and not spec.startswith("shape:"):
        script = EditScript.read(spec)
        scene = load_scene(spec_of(script), supports=supports, up=up) if (supports or up) else _start_scene(script, None)
        start = Design(scene, density=script.density if density is None else density,
                       thickness=script.thickness if thickness is None else thickness, w_max=script.w_max)
        script = replace(script, solve={**SOLVE_DEFAULTS, **dict(script.solve)})
        return EditLog.from_script(script, start, scene_spec=_portable(spec_of(script)))
    scene = load_scene(spec, supports=supports, up=up)
    start = Design(scene, density=2000.0 if density is None else density, thickness=0.1 if thickness is None else thickness)
    return EditLog(start, scene_spec=_portable(spec), solve=SOLVE_DEFAULTS)


def spec_of(script) -> str:
    if script.scene is None:
        raise InputError("the edit script names no [start] scene; give it one (scene = \"FILE\" or \"shape:NAME\")")
    s = script.scene
    if not s.startswith("shape:") and script.base is not None and not Path(s).is_absolute():
        s = str(script.base / s)
    return s


def _portable(spec: str) -> str:
    """The scene as the saved script names it: absolute, so the script works from any folder."""
    return spec if spec.startswith("shape:") else str(Path(spec).resolve())


def run_design(args: argparse.Namespace) -> int:
    """Start the server and serve until interrupted (see the module docstring)."""
    log = open_session(args.scene, up=args.up, supports=args.supports, density=args.density,
                       thickness=args.thickness)
    sock = bind_loopback(args.port)
    port = sock.getsockname()[1]
    token = new_token()
    inputs = tuple(p for p in (args.scene, args.supports) if p and not p.startswith("shape:") and Path(p).exists())
    app = create_app(DesignServer(log=log, root=Path.cwd(), inputs=inputs), token, port=port)
    url = f"http://127.0.0.1:{port}/?token={token}"
    print(url, flush=True)
    if not args.no_browser:
        import webbrowser

        webbrowser.open(url)
    try:
        serve(app, sock)
    except KeyboardInterrupt:
        return EXIT_CODES["interrupted"]
    finally:
        sock.close()
        sys.stdout.flush()
    return EXIT_CODES["ok"]


COMMANDS: dict[str, Command] = {
    "design": Command(help="interactive design tool in the browser (local server on 127.0.0.1)",
                      add_arguments=add_design_arguments, run=run_design),
}
