"""Latency of ``selfsupport design``: from an edit sent to the new frame received.

    python -m studies.design_latency [--scene shape:pillar_vault:1200 | --scenes DIR (lilium)]
                                     [--steps 30] [--step 0.001] [--out DIR]

A real server (uvicorn on 127.0.0.1, :mod:`selfsupport.app.server`) and a scripted WebSocket
client in this process. Each row is one kind of interaction, ``--steps`` edits, each sent when
the previous frame has arrived (a user dragging no faster than the tool answers):

* ``drag (height)`` / ``drag (full)`` / ``drag (top view)`` — the steps of one drag of the
  handle nearest the middle, ``--step`` of the bounding-box diagonal further each time (a drag
  step replaces the last edit: the Laplacian edit is redone from the pre-drag design);
* ``pin / unpin`` — alternately pinning and freeing a free vertex;
* ``density`` — the density slider moved by 1% each time.

``--browser`` adds rows measured in the page itself, in headless Chromium (Debian's chromium and
chromium-driver, through Selenium): from the page sending a drag step to the new frame drawn
(``Plotly.react`` done and the next animation frame), the way a user sees it, with the time the
frame reached the page and the time ``Plotly.react`` took. Headless Chromium draws WebGL in
software (SwiftShader), on the same CPUs as the solver: a pessimistic figure for a desktop.

Columns: median and 90th percentile of the end-to-end latency (send → frame parsed by the
client), of the solve alone (the frame's ``wall_time``) and of the server's time from receiving
the edit to the frame's payload built (the edit, the solve, the payload); iterations (median)
and the frame's size in bytes of JSON. A benchmark, not a timed test: the numbers depend on the
machine and on its load (printed). ``--out DIR`` writes the rows to ``DIR/design_latency.csv``,
each stamped (:func:`studies.common.run_stamp`) and with the scene's size.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import threading
import time
from pathlib import Path

import numpy as np

from .common import STAMP_COLUMNS, Column, run_stamp, write_csv

#: the CSV's columns (``--out``)
COLUMNS = (Column("scene", "scene"), Column("vertices", "V"), Column("edges", "E"), Column("step", "step / diag"),
           Column("interaction", "interaction"), Column("median_ms", "median [ms]"), Column("p90_ms", "p90 [ms]"),
           Column("solve_ms", "solve [ms]"), Column("solve_p90_ms", "solve p90 [ms]"),
           Column("server_ms", "server [ms]"), Column("server_p90_ms", "server p90 [ms]"),
           Column("iterations", "iterations"), Column("frame_kb", "frame [kB]"), Column("steps", "edits"),
           *STAMP_COLUMNS)


def _stats(xs: list[float]) -> tuple[float, float]:
    xs = sorted(xs)
    return statistics.median(xs), xs[min(len(xs) - 1, int(0.9 * len(xs)))]


async def _bench(url: str, origin: str, steps: int, step: float) -> list[dict]:
    import websockets

    rows = []
    async with websockets.connect(url, origin=origin, max_size=2**26) as ws:
        frames: asyncio.Queue = asyncio.Queue()
        states: asyncio.Queue = asyncio.Queue()

        async def reader():
            async for text in ws:
                m = json.loads(text)
                if m["type"] == "frame":
                    frames.put_nowait((time.perf_counter(), m, len(text)))
                elif m["type"] == "state":
                    states.put_nowait(m)

        task = asyncio.create_task(reader())
        _, f0, _ = await frames.get()
        V = np.reshape(f0["vertices"], (-1, 3))
        diag = float(np.linalg.norm(np.ptp(V, axis=0)))
        free = np.setdiff1d(np.arange(len(V)), f0["supports"])
        mid = V[:, :2].min(0) * 0.5 + V[:, :2].max(0) * 0.5
        h = int(free[np.argmin(np.linalg.norm(V[free, :2] - mid, axis=1))])
        pin_v = int(free[len(free) // 4])
        d = step * diag
        kinds = {
            "drag (height)": lambda k: ({"op": "move", "select": {"vertices": [h]}, "offset": [0, 0, d * k],
                                         "mode": "height"}, "dh"),
            "drag (full)": lambda k: ({"op": "move", "select": {"vertices": [h]}, "offset": [d * k * 0.6, 0, d * k * 0.8],
                                       "mode": "full"}, "df"),
            "drag (top view)": lambda k: ({"op": "move", "select": {"vertices": [h]}, "offset": [d * k, 0, 0],
                                           "mode": "top_view"}, "dt"),
            "pin / unpin": lambda k: ({"op": "pin" if k % 2 else "unpin", "select": {"vertices": [pin_v]}}, None),
            "density": lambda k: ({"op": "material", "density": 2000.0 * (1 + 0.01 * k)}, None),
        }
        for name, make in kinds.items():
            e2e, solve, server, its, size = [], [], [], [], []
            for k in range(1, steps + 1):
                edit, drag = make(k)
                t0 = time.perf_counter()
                await ws.send(json.dumps({"type": "edit", "edit": edit, "drag": drag}))
                st = await states.get()
                while True:
                    t1, f, n = await frames.get()
                    if f["seq"] >= st["seq"]:
                        break
                e2e.append(t1 - t0)
                solve.append(f["wall_time"])
                server.append(f["latency_s"])
                its.append(f["iterations"])
                size.append(n)
            if drag:
                await ws.send(json.dumps({"type": "drag_end"}))
            await ws.send(json.dumps({"type": "undo"}))  # back to the start for the next kind
            st = await states.get()
            while (await frames.get())[1]["seq"] < st["seq"]:
                pass
            m, p90 = _stats(e2e)
            sm, sp = _stats(solve)
            vm, vp = _stats(server)
            rows.append({"interaction": name, "median_ms": 1e3 * m, "p90_ms": 1e3 * p90, "solve_ms": 1e3 * sm,
                         "solve_p90_ms": 1e3 * sp, "server_ms": 1e3 * vm, "server_p90_ms": 1e3 * vp,
                         "iterations": statistics.median(its), "frame_kb": statistics.median(size) / 1024,
                         "vertices": len(V), "edges": len(f0["edges"]) // 2, "step": step, "steps": steps})
        task.cancel()
        rows.append({"interaction": f"({len(V)} vertices, {len(f0['edges']) // 2} edges, step {step:g} of the "
                                    f"diagonal = {d * 1000:.1f} mm)"})
    return rows


#: The page's side of ``--browser``: drag steps sent by the page, each when the previous one is drawn.
_PAGE_BENCH = """
const [h, steps, d, mode, done] = arguments;
(async () => {
  const S = window.ssDesign, out = [], drawn = [], recv = [];
  const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
  for (let k = 1; k <= steps; k++) {
    const before = S.st.state.seq, t0 = performance.now();
    S.sendEdit({op: 'move', select: {vertices: [h]}, offset: mode === 'height' ? [0, 0, d * k] : [0.6 * d * k, 0, 0.8 * d * k],
                mode}, 'bench-' + mode);
    while (!(S.st.state.seq > before && S.st.drawn >= S.st.state.seq)) await sleep(1);
    await new Promise((r) => requestAnimationFrame(() => r()));
    out.push(performance.now() - t0);
    drawn.push(S.st.drawMs.net);
    recv.push(S.st.latency[S.st.latency.length - 1]);
  }
  S.send({type: 'drag_end'});
  S.send({type: 'undo'});
  done([out, drawn, recv]);
})();
"""


def _browser_rows(url: str, steps: int, step: float) -> list[dict]:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = "/usr/bin/chromium"
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--window-size=1500,950",
              "--disable-dev-shm-usage", "--no-first-run", "--proxy-server=http://127.0.0.1:9"):
        opts.add_argument(a)
    drv = webdriver.Chrome(service=Service(executable_path="/usr/bin/chromedriver"), options=opts)
    try:
        drv.set_script_timeout(600)
        drv.get(url)
        t0 = time.time()
        while not drv.execute_script("return !!(window.ssDesign && ssDesign.st.frame && ssDesign.st.drawn >= 0 "
                                     "&& ssDesign.st.state)"):
            if time.time() - t0 > 120:
                raise RuntimeError("the page did not draw its first frame within 120 s")
            time.sleep(0.1)
        f = drv.execute_script("return ssDesign.st.frame")
        V = np.reshape(f["vertices"], (-1, 3))
        free = np.setdiff1d(np.arange(len(V)), f["supports"])
        mid = 0.5 * (V[:, :2].min(0) + V[:, :2].max(0))
        h = int(free[np.argmin(np.linalg.norm(V[free, :2] - mid, axis=1))])
        d = step * float(np.linalg.norm(np.ptp(V, axis=0)))
        rows = []
        for mode in ("height", "full"):
            ms, draw_ms, recv_ms = drv.execute_async_script(_PAGE_BENCH, h, steps, d, mode)
            m, p90 = _stats(ms)
            rows.append({"interaction": f"page: drag ({mode}), drawn", "median_ms": m, "p90_ms": p90,
                         "draw_ms": _stats(draw_ms), "recv_ms": _stats(recv_ms)})
            time.sleep(1.0)  # the undo's frame
        return rows
    finally:
        drv.quit()


def run(scene: str, *, steps: int = 30, step: float = 0.001, root: Path | None = None,
        browser: bool = False) -> list[dict]:
    """Start a server on ``scene`` and measure (see the module docstring)."""
    from selfsupport.app.server import DesignServer, bind_loopback, create_app, new_token, serve
    from selfsupport.cli.design import open_session

    log = open_session(scene)
    sock = bind_loopback(0)
    port = sock.getsockname()[1]
    token = new_token()
    srv = DesignServer(log=log, root=root or Path.cwd())
    app = create_app(srv, token, port=port)
    threading.Thread(target=serve, args=(app, sock), daemon=True).start()
    try:
        rows = asyncio.run(_bench(f"ws://127.0.0.1:{port}/ws?token={token}", f"http://127.0.0.1:{port}", steps, step))
        if browser:
            rows[-1:-1] = _browser_rows(f"http://127.0.0.1:{port}/?token={token}", steps, step)
        return rows
    finally:
        srv.stop()


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default=None, help="scene file or shape:NAME[:N] (default shape:pillar_vault:1200)")
    p.add_argument("--scenes", default=None, help="the paper's scenes folder: use its lilium.sss (1,201 vertices)")
    p.add_argument("--steps", type=int, default=30)
    p.add_argument("--step", type=float, default=0.001, help="drag step, fraction of the bounding-box diagonal")
    p.add_argument("--browser", action="store_true", help="also measure in the page (headless Chromium, drawn frames)")
    p.add_argument("--out", type=Path, default=None, help="folder for design_latency.csv")
    a = p.parse_args(argv)
    scene = a.scene or (str(Path(a.scenes) / "lilium.sss") if a.scenes else "shape:pillar_vault:1200")
    stamp = run_stamp()
    rows = run(scene, steps=a.steps, step=a.step, browser=a.browser)
    if a.out is not None:
        a.out.mkdir(parents=True, exist_ok=True)
        name = Path(scene).stem if not scene.startswith("shape:") else scene
        write_csv(a.out / "design_latency.csv", [{**r, "scene": name, **stamp} for r in rows if "median_ms" in r],
                  COLUMNS)
    import os

    print(f"design latency: {scene}, {a.steps} edits per row, each sent when the previous frame arrived; "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print(f"| {'interaction':<16} | median [ms] | p90 [ms] | solve [ms] (p90) | server [ms] (p90) | iterations | frame [kB] |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        if "median_ms" not in r:
            print(f"| {r['interaction']} | | | | | | |")
            continue
        if "solve_ms" not in r:
            (dm, dp), (rm, rp) = r["draw_ms"], r["recv_ms"]
            print(f"| {r['interaction']} | {r['median_ms']:.0f} | {r['p90_ms']:.0f} | frame received {rm:.0f} ({rp:.0f}) "
                  f"| Plotly.react {dm:.0f} ({dp:.0f}) | | |")
            continue
        print(f"| {r['interaction']:<16} | {r['median_ms']:.0f} | {r['p90_ms']:.0f} | {r['solve_ms']:.0f} "
              f"({r['solve_p90_ms']:.0f}) | {r['server_ms']:.0f} ({r['server_p90_ms']:.0f}) | {r['iterations']:.0f} | "
              f"{r['frame_kb']:.0f} |")


if __name__ == "__main__":
    main()
