"""The web side of ``selfsupport design``: a Starlette app on 127.0.0.1 with one WebSocket.

The page (``static/``: plain ES modules and plotly.js from the installed ``plotly`` package,
nothing fetched from the network) sends edits over the WebSocket; the server applies them to
the :class:`~selfsupport.app.session.EditLog` at once, answers with a ``state`` message,
and hands the design to the :class:`~selfsupport.app.session.SolveWorker`, whose frames are
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
    save      {"what": "script"|"scene"|"network"|"figures", "path": "relative/name",
               "overwrite": ["name", ...]}             (optional) existing files the user agreed to replace

Every message is checked before it acts (:meth:`DesignServer.answer`): a message that is not
a JSON object, a binary frame, a NaN or infinite number, an out-of-range index or a bad edit
is answered with ``{"type": "error", ...}`` and changes nothing; the connection stays. Edits run
in threads of their own, off the event loop, and one that runs past
:attr:`DesignServer.edit_time_limit` is answered with an error and dropped (the other pages go
on meanwhile).

Save writes a new file, or one this session wrote itself and nobody changed since; any other
existing file is replaced only when the message's ``overwrite`` names it (the page asks first:
the error reply lists the files in ``exists``).
"""
from __future__ import annotations

import asyncio
import hmac
import json
import os
import secrets
import socket
import threading
import time
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from selfsupport.app.session import EditLog, SolveWorker
from selfsupport.core.errors import InputError, SelfSupportError
from selfsupport.design.edits import check_values, edit_from_dict
from selfsupport.figures.render import FigureInput, render
from selfsupport.io import write_network
from selfsupport.io.atomic import atomic_write_text
from selfsupport.io.safety import same_file, write_target
from selfsupport.io.sss import write_scene_sss

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


def parse_message(data: str | bytes | None) -> dict:
    """A page's message (the text of a WebSocket frame) as a dict; :class:`InputError` for a
    binary frame, text that is not JSON, JSON nested too deeply or not an object."""
    if not isinstance(data, str):
        raise InputError("the server takes text frames holding JSON objects, not binary frames")
    try:
        msg = json.loads(data)
    except json.JSONDecodeError as e:
        raise InputError(f"the message is not valid JSON ({e.msg}, column {e.colno}); send a JSON object "
                         "with a 'type'") from None
    except RecursionError:
        raise InputError("the message is nested too deeply; send a flat JSON object with a 'type'") from None
    if not isinstance(msg, dict):
        raise InputError("a message is a JSON object with a 'type'")
    return msg


def _integer(msg: Mapping[str, Any], key: str, what: str) -> int:
    v = msg.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or v != int(v):
        raise InputError(f"{what}: '{key}' must be an integer, got {v!r}")
    return int(v)


def _number(msg: Mapping[str, Any], key: str, what: str, default: float) -> float:
    v = msg.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise InputError(f"{what}: '{key}' must be a number, got {v!r}")
    return float(v)


def _stamp(path: Path) -> tuple | None:
    """What identifies a file's content as the one written: device, inode, mtime, size."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return None
    return (st.st_dev, st.st_ino, st.st_mtime_ns, st.st_size)


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
    edit_time_limit: float = 30.0  # seconds an edit may take before it is dropped
    max_threads: int = 8  # messages being answered at once (edits past their limit still count)
    written: dict = field(default_factory=dict)  # resolved path -> _stamp of the files save wrote
    _t_received: float = 0.0
    _threads: set = field(default_factory=set)  # the threads answering messages now

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop
        if self.worker is None:
            self.worker = SolveWorker(self._emit, options=self.log.solve, analysis=self.analysis)
            self.worker.submit(self.log.seq, self.log.design)

    def stop(self, timeout: float = 30.0) -> None:
        """Stop the solver (waiting at most ``timeout`` s for each of its threads)."""
        if self.worker is not None:
            self.worker.close(timeout)
            self.worker = None

    # -- from the worker thread ------------------------------------------------------------
    def _emit(self, msg: dict) -> None:
        try:
            text = json.dumps(msg, allow_nan=False)
        except (TypeError, ValueError) as e:  # never keep (and resend to every page) an unsendable frame
            msg = {"type": "error", "seq": msg.get("seq"), "what": msg.get("type"), "message": f"cannot send: {e}"}
            text = json.dumps(msg)
        if msg["type"] == "frame":
            self.last_frame = msg
        elif msg["type"] == "analysis":
            self.last_analysis = msg
        loop = self.loop
        if loop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(self._broadcast_text, text)
            except RuntimeError:  # the loop closed meanwhile (shutting down)
                pass

    def _broadcast_text(self, text: str) -> None:
        for q in list(self.clients):
            q.put_nowait(text)

    # -- messages ----------------------------------------------------------------------------
    def state(self) -> dict:
        log = self.log
        return {"type": "state", "seq": log.seq, "n_edits": len(log.edits), "can_undo": log.can_undo,
                "can_redo": log.can_redo, "edits": [e.to_dict() for e in log.edits[-50:]],
                "solved_seq": self.worker.last_seq if self.worker else -1}

    def error(self, msg: Any, e: BaseException) -> dict:
        """The error reply to ``msg`` (a message, or ``None`` when it could not be read)."""
        kind = msg.get("type") if isinstance(msg, Mapping) else None
        text = str(e) if isinstance(e, SelfSupportError) else f"{type(e).__name__}: {e}"
        return {"type": "error", "what": kind if isinstance(kind, str) else "message", "message": text,
                "seq": self.log.seq}

    async def answer(self, data: str | bytes | None) -> list[str]:
        """The replies (JSON texts) to one WebSocket frame's ``data``. Whatever the frame holds,
        this returns: a message that cannot be read or acted on gets an error reply. The message
        is handled in a daemon thread of its own (:meth:`handle`), an edit within
        :attr:`edit_time_limit`."""
        msg = None
        try:
            msg = parse_message(data)
            if len(self._threads) >= self.max_threads:
                raise InputError("the server is busy with earlier messages that ran too long; wait, or restart "
                                 "`selfsupport design`")
            limit = float(self.edit_time_limit)
            deadline = time.perf_counter() + limit
            try:  # (a little longer than the deadline: an edit that ended in time has its answer sent)
                replies = await _in_thread(self, self.handle, msg, deadline, timeout=limit + 1.0)
            except TimeoutError:
                kind = msg.get("type")
                raise InputError(f"{kind}: not done within {limit:g} s; " + (
                    "dropped, nothing changed (an edit of a smaller region is quicker)" if kind == "edit"
                    else "its answer is not sent")) from None
            return [json.dumps(r, allow_nan=False) for r in replies]
        except Exception as e:  # noqa: BLE001 - one bad message never ends the connection
            return [json.dumps(self.error(msg, e))]

    def handle(self, msg: Mapping[str, Any], deadline: float | None = None) -> list[dict]:
        """Act on one message from a page; the replies to send to that page. Raises
        :class:`InputError` (nothing changed) when the message is not valid; an edit that ends
        after ``deadline`` (``time.perf_counter()``) is dropped."""
        check_values(msg, "message")  # finite numbers, 64-bit integers, bounded nesting
        kind = msg.get("type")
        log = self.log
        self._t_received = time.perf_counter()
        if kind == "edit":
            e = msg.get("edit")
            if not isinstance(e, Mapping):
                raise InputError("edit: 'edit' must be an object like {\"op\": \"pin\", \"select\": {...}}")
            edit = edit_from_dict(dict(e))
            drag = msg.get("drag")
            if not (drag is None or isinstance(drag, str)):
                raise InputError(f"edit: 'drag' is null or a drag id (a string), got {drag!r}")
            log.apply(edit, drag=drag, deadline=deadline)
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
            v = _integer(msg, "vertex", "probe")
            d = log.design
            if not 0 <= v < d.scene.mesh.n_vertices:
                raise InputError(f"probe: vertex {v} is outside 0..{d.scene.mesh.n_vertices - 1}")
            # each hull solve of the bisection within 1-120 s (the probe's own limit, not the page's)
            limit = min(max(_number(msg, "time_limit", "probe", 20.0), 1.0), 120.0)
            self.worker.probe(log.seq, d, v, time_limit=limit)
            return []
        if kind == "save":
            over = msg.get("overwrite") or []
            if not (isinstance(over, list) and all(isinstance(x, str) for x in over)):
                raise InputError("save: 'overwrite' is a list of the file names to replace")
            return [self.save(str(msg.get("what", "")), msg.get("path"), overwrite=over)]
        raise InputError(f"unknown message type {kind!r}; send one of edit, drag_end, undo, redo, state, probe, save")

    def _resolve(self) -> None:
        self.worker.submit(self.log.seq, self.log.design, t0=self._t_received)

    def save(self, what: str, name: Any, *, overwrite: Any = ()) -> dict:
        """Write the edit script, the scene, the network or the figures below :attr:`root`.

        An existing file is replaced only when this session wrote it (and it is unchanged since)
        or ``overwrite`` names it (relative to :attr:`root`); otherwise the reply is an error
        listing the files in ``exists`` and nothing is written. The files the session was opened
        from are never replaced."""

        if what not in SAVE_KINDS:
            raise InputError(f"save: 'what' is one of {', '.join(SAVE_KINDS)}")
        path = safe_path(self.root, name, SAVE_KINDS[what])
        root_r = self.root.resolve()
        targets = [path] if what != "figures" else [path.with_name(f"{path.stem}-{k}.png") for k in _FIGURES]
        exists = []
        for p in targets:
            write_target(p, what=what)  # refuses directories, devices, FIFOs
            for src in self.inputs:
                if same_file(p, src):
                    raise InputError(f"refusing to write over {p.relative_to(root_r)}: the session was opened "
                                     "from it; give another name")
            stamp = _stamp(p)
            if stamp is not None and self.written.get(str(p)) != stamp:
                exists.append(str(p.relative_to(root_r)))
        if not set(exists) <= set(overwrite):
            return {"type": "error", "what": "save", "seq": self.log.seq, "exists": exists,
                    "message": f"save: {', '.join(exists)} already exists (not written by this design session, "
                               "or changed since); confirm to replace it, or give another name"}
        path.parent.mkdir(parents=True, exist_ok=True)
        if not path.parent.resolve().is_relative_to(self.root.resolve()):  # pragma: no cover - raced symlink
            raise InputError("refusing: the folder leads outside the working folder")
        written = [path]
        if what == "script":
            atomic_write_text(path, self.log.script().dumps())
        elif what == "scene":

            write_scene_sss(path, self.log.design.scene)
        else:
            res = self.worker.last if self.worker else None
            if res is None or self.worker.last_seq != self.log.seq:
                raise InputError("save: the current design is not solved yet; wait for its frame")
            if what == "network":

                write_network(path, res, design={"edits": [e.to_dict() for e in self.log.edits]})
            else:

                written = []
                for kind, p in zip(_FIGURES, targets):
                    try:
                        render(kind, FigureInput(res.network, title=f"design: {kind}"), p)
                        written.append(p)
                    except (SelfSupportError, ValueError) as e:
                        if kind == "network":
                            raise
                        _ = e  # the analysis figures need a network the Airy analysis accepts
        for p in written:
            self.written[str(p)] = _stamp(p)
        rel = [str(p.relative_to(root_r)) for p in written]
        return {"type": "saved", "what": what, "paths": rel}


#: The figures ``save`` writes, as NAME-KIND.png.
_FIGURES = ("network", "airy", "reciprocal")


async def _in_thread(server: DesignServer, fn: Any, *args: Any, timeout: float) -> Any:
    """``fn(*args)`` in a daemon thread of its own, awaited for at most ``timeout`` s
    (:class:`TimeoutError` after). A daemon thread, not the loop's executor: a long edit keeps
    neither the event loop nor the process's exit (SIGTERM) waiting."""
    loop = asyncio.get_running_loop()
    fut = loop.create_future()

    def settle(ok: bool, value: Any) -> None:
        if not fut.done():
            fut.set_result(value) if ok else fut.set_exception(value)

    def run() -> None:
        try:
            out = (True, fn(*args))
        except BaseException as e:  # noqa: BLE001 - handed to the awaiting coroutine
            out = (False, e)
        finally:
            server._threads.discard(threading.current_thread())
        try:
            loop.call_soon_threadsafe(settle, *out)
        except RuntimeError:  # the loop closed meanwhile (shutting down)
            pass

    th = threading.Thread(target=run, name="selfsupport-design-message", daemon=True)
    server._threads.add(th)
    th.start()
    return await asyncio.wait_for(fut, timeout)


# ------------------------------------------------------------------------------- the app
def create_app(server: DesignServer, token: str, *, port: int | None = None) -> Any:
    """The Starlette application of ``server`` guarded by ``token`` (see the module docstring).
    ``port``: the port the ``Host`` and ``Origin`` headers must name (``None``: any port on
    127.0.0.1 / localhost, for tests)."""

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
            for text in await server.answer('{"type": "state"}'):
                q.put_nowait(text)
            while True:
                event = await websocket.receive()
                if event["type"] == "websocket.disconnect":
                    break
                for text in await server.answer(event.get("text", event.get("bytes"))):
                    q.put_nowait(text)
        except WebSocketDisconnect:
            pass
        except asyncio.CancelledError:  # the server stops (SIGTERM, Ctrl+C) while a message is answered
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
            server.stop(timeout=_STOP_WAIT)

    app = Starlette(routes=[Route("/", index), Route("/static/{name}", static), WebSocketRoute("/ws", ws)],
                    lifespan=lifespan)
    app.add_middleware(Guard)
    return app


#: The page loads scripts and styles from this server only and connects to it only.
_CSP = ("default-src 'none'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
        "img-src 'self' data: blob:; connect-src 'self'; worker-src blob:; font-src 'self' data:; "
        "base-uri 'none'; form-action 'none'; frame-ancestors 'none'")


#: Seconds a stopping server waits for open connections' messages and for the solver's threads
#: (both daemons: the process ends without them).
_STOP_WAIT = 1.0


def bind_loopback(port: int = 0) -> Any:
    """A listening TCP socket on 127.0.0.1:``port`` (0: a free port) — the loopback address
    only, never all interfaces. SO_REUSEADDR: a restart on the same port binds while the last
    run's connections linger in TIME_WAIT (on Linux it never lets two servers listen on a port)."""

    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(("127.0.0.1", int(port)))
        sock.listen(128)  # the printed URL works at once (connections wait for the server)
    except OSError as e:
        sock.close()
        raise InputError(f"cannot listen on 127.0.0.1:{port} ({e.strerror}); choose another --port") from None
    return sock


def serve(app: Any, sock: Any) -> None:
    """Run ``app`` with uvicorn on the bound socket ``sock`` until interrupted."""
    import uvicorn

    # SIGTERM / Ctrl+C: messages still being answered are cancelled after _STOP_WAIT s
    config = uvicorn.Config(app, log_level="warning", ws="websockets-sansio", lifespan="on", ws_max_size=4 * 2**20,
                            timeout_graceful_shutdown=_STOP_WAIT)
    uvicorn.Server(config).run(sockets=[sock])
