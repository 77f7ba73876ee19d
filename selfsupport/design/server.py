"""The web side of ``selfsupport design``: a Starlette app on 127.0.0.1 with one WebSocket.

The page (``static/``: plain ES modules and plotly.js from the installed ``plotly`` package,
nothing fetched from the network) sends edits over the WebSocket; the server applies them to
the :class:`~selfsupport.design.session.EditLog` at once, answers with a ``state`` message,
and hands the design to the :class:`~selfsupport.design.session.SolveWorker`, whose frames are
pushed to every connected page as they come.

Security (a local tool that writes files):

* bound to 127.0.0.1 only (:func:`serve`); the ``Host`` header must name that address and port
  (no DNS rebinding);
* every request needs the session's token (made afresh at each start, :func:`new_token`):
  ``?token=`` on the URL the command prints, then an HttpOnly, SameSite=Strict cookie set by
  the page; otherwise 403;
* a request whose ``Origin`` is not this server's own is refused (403; a WebSocket is closed
  before the handshake completes) — another site open in the same browser cannot drive it;
* files are written only below the working folder (:func:`safe_path`): no absolute paths, no
  ``..``, no symlink that leads out; static files come from a fixed list, never a path join.

Messages from the page (JSON objects with a ``type``)::

    edit      {"edit": {op, ...}, "drag": id | null}   an edit of selfsupport.design.edits
    drag_end  {}                                       the drag is over
    undo / redo / state
    probe     {"vertex": i}                            max load at a vertex (stability)
    save      {"what": "script"|"scene"|"network"|"figures", "path": "relative/name"}
"""
from __future__ import annotations

import asyncio
import hmac
import json
import secrets
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from ..errors import InputError, SelfSupportError
from .edits import edit_from_dict
from .session import EditLog, SolveWorker

__all__ = ["DesignServer", "create_app", "bind_loopback", "serve", "new_token", "safe_path", "STATIC_FILES", "COOKIE"]

COOKIE = "selfsupport_token"
_STATIC = Path(__file__).parent / "static"


def _plotly_js() -> Path:
    import plotly

    return Path(plotly.__file__).parent / "package_data" / "plotly.min.js"


#: The only files the server sends besides the page: name -> (path getter, media type).
STATIC_FILES: dict[str, tuple[Any, str]] = {
    "app.js": (lambda: _STATIC / "app.js", "text/javascript"),
    "view.js": (lambda: _STATIC / "view.js", "text/javascript"),
    "style.css": (lambda: _STATIC / "style.css", "text/css"),
    "plotly.min.js": (_plotly_js, "text/javascript"),
}
#: What ``save`` writes: name -> the file suffix (added when the name lacks it)
SAVE_KINDS: dict[str, str] = {"script": ".toml", "scene": ".sss", "network": ".json", "figures": ".png"}


def new_token() -> str:
    """A fresh random token (256 bits, URL-safe)."""
    return secrets.token_urlsafe(32)


def safe_path(root: Path, name: str, suffix: str) -> Path:
    """``root / name`` when it stays below ``root`` (resolved, symlinks followed), with
    ``suffix`` added when missing; :class:`InputError` otherwise."""
    if not isinstance(name, str) or not name.strip():
        raise InputError("give a file name (relative to the working folder)")
    p = Path(name)
    if p.is_absolute() or any(part == ".." for part in p.parts) or "\x00" in name:
        raise InputError(f"refusing {name!r}: give a path inside the working folder (no absolute path, no '..')")
    if p.suffix.lower() != suffix:
        p = p.with_name(p.name + suffix)
    root_r = root.resolve()
    full = (root_r / p).resolve()
    if full != root_r and root_r not in full.parents:
        raise InputError(f"refusing {name!r}: it leads outside the working folder")
    return full


@dataclass
class DesignServer:
    """The session state shared by the app's connections: the log, the worker, the pages."""

    log: EditLog
    root: Path
    analysis: bool = True
    clients: set = field(default_factory=set)
    loop: asyncio.AbstractEventLoop | None = None
    last_frame: dict | None = None
    last_analysis: dict | None = None
    worker: SolveWorker | None = None
    inputs: tuple = ()  # files the session was opened from: never written over
    _t_received: float = 0.0

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop
        if self.worker is None:
            self.worker = SolveWorker(self._emit, options=self.log.solve, analysis=self.analysis)
            self.worker.submit(self.log.seq, self.log.design)

    def stop(self) -> None:
        if self.worker is not None:
            self.worker.close()
            self.worker = None

    # -- from the worker thread ------------------------------------------------------------
    def _emit(self, msg: dict) -> None:
        if msg["type"] == "frame":
            self.last_frame = msg
        elif msg["type"] == "analysis":
            self.last_analysis = msg
        loop = self.loop
        if loop is not None and not loop.is_closed():
            text = json.dumps(msg, allow_nan=False)
            loop.call_soon_threadsafe(self._broadcast_text, text)

    def _broadcast_text(self, text: str) -> None:
        for q in list(self.clients):
            q.put_nowait(text)

    # -- messages ----------------------------------------------------------------------------
    def state(self) -> dict:
        log = self.log
        return {"type": "state", "seq": log.seq, "n_edits": len(log.edits), "can_undo": log.can_undo,
                "can_redo": log.can_redo, "edits": [e.to_dict() for e in log.edits[-50:]],
                "solved_seq": self.worker.last_seq if self.worker else -1}

    def handle(self, msg: Mapping[str, Any]) -> list[dict]:
        """Act on one message from a page; the replies to send to that page."""
        kind = msg.get("type")
        log = self.log
        self._t_received = time.perf_counter()
        if kind == "edit":
            edit = edit_from_dict(dict(msg.get("edit") or {}))
            drag = msg.get("drag")
            log.apply(edit, drag=None if drag is None else str(drag))
            self._resolve()
            return [self.state()]
        if kind == "drag_end":
            log.end_drag()
            return [self.state()]
        if kind in ("undo", "redo"):
            (log.undo if kind == "undo" else log.redo)()
            self._resolve()
            return [self.state()]
        if kind == "state":
            out = [self.state()]
            out += [m for m in (self.last_frame, self.last_analysis) if m is not None]
            return out
        if kind == "probe":
            v = int(msg.get("vertex", -1))
            d = log.design
            if not 0 <= v < d.scene.mesh.n_vertices:
                raise InputError(f"probe: vertex {v} is outside 0..{d.scene.mesh.n_vertices - 1}")
            # each hull solve of the bisection within 1-120 s (the probe's own limit, not the page's)
            limit = min(max(float(msg.get("time_limit", 20.0)), 1.0), 120.0)
            self.worker.probe(log.seq, d, v, time_limit=limit)
            return []
        if kind == "save":
            return [self.save(str(msg.get("what", "")), msg.get("path"))]
        raise InputError(f"unknown message type {kind!r}")

    def _resolve(self) -> None:
        self.worker.submit(self.log.seq, self.log.design, t0=self._t_received)

    def save(self, what: str, name: Any) -> dict:
        """Write the edit script, the scene, the network or the figures below :attr:`root`."""
        from ..io.atomic import atomic_write_text
        from ..io.safety import same_file, write_target

        if what not in SAVE_KINDS:
            raise InputError(f"save: 'what' is one of {', '.join(SAVE_KINDS)}")
        path = safe_path(self.root, name, SAVE_KINDS[what])
        write_target(path, what=what)  # refuses directories, devices, FIFOs
        for src in self.inputs:
            if same_file(path, src):
                raise InputError(f"refusing to write over {name!r}: the session was opened from it; give another name")
        path.parent.mkdir(parents=True, exist_ok=True)
        if not path.parent.resolve().is_relative_to(self.root.resolve()):  # pragma: no cover - raced symlink
            raise InputError("refusing: the folder leads outside the working folder")
        written = [path]
        if what == "script":
            atomic_write_text(path, self.log.script().dumps())
        elif what == "scene":
            from ..io.sss import write_scene_sss

            write_scene_sss(path, self.log.design.scene)
        else:
            res = self.worker.last if self.worker else None
            if res is None or self.worker.last_seq != self.log.seq:
                raise InputError("save: the current design is not solved yet; wait for its frame")
            if what == "network":
                from ..io import write_network

                write_network(path, res, design={"edits": [e.to_dict() for e in self.log.edits]})
            else:
                from ..figures.render import FigureInput, render

                written = []
                for kind in ("network", "airy", "reciprocal"):
                    p = path.with_name(f"{path.stem}-{kind}.png")
                    try:
                        render(kind, FigureInput(res.network, title=f"design: {kind}"), p)
                        written.append(p)
                    except (SelfSupportError, ValueError) as e:
                        if kind == "network":
                            raise
                        _ = e  # the analysis figures need a network the Airy analysis accepts
        rel = [str(p.relative_to(self.root.resolve())) for p in written]
        return {"type": "saved", "what": what, "paths": rel}


# ------------------------------------------------------------------------------- the app
def create_app(server: DesignServer, token: str, *, port: int | None = None) -> Any:
    """The Starlette application of ``server`` guarded by ``token`` (see the module docstring).
    ``port``: the port the ``Host`` and ``Origin`` headers must name (``None``: any port on
    127.0.0.1 / localhost, for tests)."""
    from contextlib import asynccontextmanager

    from starlette.applications import Starlette
    from starlette.responses import FileResponse, HTMLResponse, PlainTextResponse
    from starlette.routing import Route, WebSocketRoute
    from starlette.websockets import WebSocket, WebSocketDisconnect

    def host_ok(host: str | None) -> bool:
        if not host:
            return False
        name, _, p = host.rpartition(":")
        if not name:
            name, p = p, ""
        return name in ("127.0.0.1", "localhost") and (port is None or p == str(port))

    def origin_ok(origin: str | None) -> bool:
        if origin is None:  # not a browser (a script with the token); browsers always send it on WebSockets
            return True
        for name in ("127.0.0.1", "localhost"):
            if port is None and origin.startswith(f"http://{name}:") and origin[len(name) + 8:].isdigit():
                return True
            if port is not None and origin == f"http://{name}:{port}":
                return True
        return False

    def token_ok(params: Mapping[str, str], cookies: Mapping[str, str]) -> bool:
        given = params.get("token") or cookies.get(COOKIE) or ""
        return hmac.compare_digest(given.encode(), token.encode())

    class Guard:
        """Host, Origin and token checks before any route (HTTP and WebSocket)."""

        def __init__(self, app: Any) -> None:
            self.app = app

        async def __call__(self, scope, receive, send) -> None:
            if scope["type"] in ("http", "websocket"):
                from starlette.requests import HTTPConnection

                conn = HTTPConnection(scope)
                why = None
                if not host_ok(conn.headers.get("host")):
                    why = "wrong Host header"
                elif not origin_ok(conn.headers.get("origin")):
                    why = "foreign Origin"
                elif not token_ok(conn.query_params, conn.cookies):
                    why = "missing or wrong token"
                if why is not None:
                    if scope["type"] == "websocket":
                        await send({"type": "websocket.close", "code": 1008, "reason": why})
                        return
                    await PlainTextResponse(f"403 forbidden: {why}", status_code=403)(scope, receive, send)
                    return
            await self.app(scope, receive, send)

    async def index(request):
        html = (_STATIC / "index.html").read_text(encoding="utf-8")
        resp = HTMLResponse(html, headers={"Cache-Control": "no-store", "Referrer-Policy": "no-referrer",
                                           "Content-Security-Policy": _CSP, "X-Content-Type-Options": "nosniff"})
        resp.set_cookie(COOKIE, token, httponly=True, samesite="strict", path="/")
        return resp

    async def static(request):
        name = request.path_params["name"]
        if name not in STATIC_FILES:
            return PlainTextResponse("not found", status_code=404)
        getter, media = STATIC_FILES[name]
        return FileResponse(getter(), media_type=media, headers={"X-Content-Type-Options": "nosniff",
                                                                 "Cache-Control": "no-cache"})

    async def ws(websocket: WebSocket):
        await websocket.accept()
        q: asyncio.Queue = asyncio.Queue()
        server.clients.add(q)

        async def pump() -> None:
            while True:
                await websocket.send_text(await q.get())

        sender = asyncio.create_task(pump())
        try:
            for m in server.handle({"type": "state"}):
                q.put_nowait(json.dumps(m, allow_nan=False))
            while True:
                text = await websocket.receive_text()
                try:
                    msg = json.loads(text)
                    if not isinstance(msg, dict):
                        raise InputError("a message is a JSON object with a 'type'")
                    # edits are quick (a Laplacian solve, a few ms); run them off the event loop anyway
                    replies = await asyncio.to_thread(server.handle, msg)
                except (SelfSupportError, ValueError, TypeError, KeyError) as e:
                    replies = [{"type": "error", "what": str(msg.get("type") if isinstance(msg, dict) else "message"),
                                "message": str(e), "seq": server.log.seq}]
                for r in replies:
                    q.put_nowait(json.dumps(r, allow_nan=False))
        except WebSocketDisconnect:
            pass
        finally:
            server.clients.discard(q)
            sender.cancel()

    @asynccontextmanager
    async def lifespan(app):
        server.start(asyncio.get_running_loop())
        try:
            yield
        finally:
            server.stop()

    app = Starlette(routes=[Route("/", index), Route("/static/{name}", static), WebSocketRoute("/ws", ws)],
                    lifespan=lifespan)
    app.add_middleware(Guard)
    return app


#: The page loads scripts and styles from this server only and connects to it only.
_CSP = ("default-src 'none'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
        "img-src 'self' data: blob:; connect-src 'self'; worker-src blob:; font-src 'self' data:; "
        "base-uri 'none'; form-action 'none'; frame-ancestors 'none'")


def bind_loopback(port: int = 0) -> Any:
    """A listening TCP socket on 127.0.0.1:``port`` (0: a free port) — the loopback address
    only, never all interfaces."""
    import socket

    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        sock.bind(("127.0.0.1", int(port)))
        sock.listen(128)  # the printed URL works at once (connections wait for the server)
    except OSError as e:
        sock.close()
        raise InputError(f"cannot listen on 127.0.0.1:{port} ({e.strerror}); choose another --port") from None
    return sock


def serve(app: Any, sock: Any) -> None:
    """Run ``app`` with uvicorn on the bound socket ``sock`` until interrupted."""
    import uvicorn

    config = uvicorn.Config(app, log_level="warning", ws="websockets-sansio", lifespan="on", ws_max_size=4 * 2**20)
    uvicorn.Server(config).run(sockets=[sock])
