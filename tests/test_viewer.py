"""The interactive HTML view: its layers and hover texts carry the network's numbers, the file
is self-contained, and headless Chromium — with every network request blocked — draws the
plot without console errors."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest

from selfsupport.core.errors import InputError  # noqa: E402
from selfsupport.core.evidence import residuals  # noqa: E402
from selfsupport.core.loads import SelfWeight  # noqa: E402
from selfsupport.core.shapes import make_shape  # noqa: E402
from selfsupport.figures.render import edge_forces  # noqa: E402
from selfsupport.figures.viewer import LAYERS, build_view, view_html, write_view  # noqa: E402
from selfsupport.methods.staggered import StaggeredLinearization  # noqa: E402

CHROMIUM = "/usr/bin/chromium"


@pytest.fixture(scope="module")
def solved():
    res = StaggeredLinearization().solve(make_shape("pillar_vault", n_vertices=200), SelfWeight())
    assert res.converged
    return res


def _analysis_available() -> bool:
    try:
        import selfsupport.analysis.airy  # noqa: F401
    except ImportError:
        return False
    return True


def _groups(fig) -> dict[str, list]:
    out: dict[str, list] = {}
    for t in fig.data:
        out.setdefault(t.legendgroup, []).append(t)
    return out


def test_layers_and_hover_carry_the_numbers(solved):
    net = solved.network
    fig, info = build_view(net, title="pillar vault")
    groups = _groups(fig)
    expected = {"reference", "network", "supports", "loads"}
    if _analysis_available():
        expected |= {"airy", "reciprocal"}
    assert set(info.layers) == expected == set(groups)
    # every layer has exactly one legend entry, so a click toggles it as a whole
    for g, traces in groups.items():
        assert sum(bool(t.showlegend) for t in traces) == 1, g
        assert [t.name for t in traces if t.showlegend] == [LAYERS[g]]
    # edge hover: one marker per edge at its midpoint, text = weight and force of that edge
    f = edge_forces(net)
    edges = next(t for t in groups["network"] if t.mode == "markers" and len(t.x) == net.mesh.n_edges)
    mid = 0.5 * (net.vertices[net.edges[:, 0]] + net.vertices[net.edges[:, 1]])
    np.testing.assert_allclose(np.c_[edges.x, edges.y, edges.z], mid)
    for k in (0, int(np.argmax(f)), net.mesh.n_edges - 1):
        assert f"force |w|‖e‖ = {f[k]:.4g} N" in edges.hovertext[k]
    # vertex hover: load and residual of each free vertex
    free = np.flatnonzero(~net.supports)
    verts = next(t for t in groups["network"] if t.name == "vertices")
    r = np.linalg.norm(residuals(vertices=net.vertices, edges=net.edges, weights=net.weights, loads=net.loads), axis=1)
    for row, i in ((0, free[0]), (len(free) - 1, free[-1])):
        txt = verts.hovertext[row]
        assert f"vertex {i}<" in txt and f"load A·F = {net.loads[i]:.4g} N" in txt
        assert f"residual ‖r‖ = {r[i]:.4g} N" in txt
    # supports: the residual there is the ground reaction; all reactions carry the total load
    sup = groups["supports"][0]
    react = [tuple(map(float, re.search(r"ground reaction = \(([^)]*)\)", s).group(1).split(", ")))
             for s in sup.hovertext]
    assert sum(z for _, _, z in react) == pytest.approx(-float(net.loads.sum()), rel=1e-3)
    # loads start hidden (legend-only); the preset buttons switch whole layers
    assert all(t.visible == "legendonly" for t in groups["loads"])
    buttons = {b.label: b.args[0]["visible"] for b in fig.layout.updatemenus[0].buttons}
    gl = [t.legendgroup for t in fig.data]
    assert [v is True for v in buttons["network"]] == [g in ("network", "supports") for g in gl]


def test_html_is_self_contained(solved, tmp_path):
    path = tmp_path / "view.html"
    write_view(path, solved.network, title="pillar vault")
    html = path.read_text(encoding="utf-8")
    assert html.lstrip().lower().startswith("<!doctype html>")
    assert not re.search(r"<script[^>]+src=", html, re.I), "external script"
    assert not re.search(r"<link[^>]+href=\"?https?:", html, re.I), "external stylesheet"
    assert len(html) > 3_000_000  # plotly.js itself is inlined
    assert 'id="selfsupport-view"' in html
    with pytest.raises(InputError, match="html"):
        write_view(tmp_path / "view.png", solved.network)


# --------------------------------------------------------------------------- browser
#: Injected at the top of <head> of a copy of the page: records console errors, uncaught
#: exceptions and plotly warnings, and writes the plot's state into the DOM for --dump-dom.
_PROBE = """<script>
window.__ss = {errors: [], warnings: []};
(function () {
  const keep = (kind) => (orig) => function (...a) {
    window.__ss[kind].push(a.map(String).join(' ')); return orig.apply(console, a); };
  console.error = keep('errors')(console.error);
  console.warn = keep('warnings')(console.warn);
  const log = console.log;
  console.log = function (...a) { const s = a.map(String).join(' ');
    if (s.startsWith('WARN')) window.__ss.warnings.push(s); return log.apply(console, a); };
  window.addEventListener('error', (e) => window.__ss.errors.push('uncaught: ' + e.message));
  window.addEventListener('unhandledrejection', (e) => window.__ss.errors.push('rejection: ' + e.reason));
  setInterval(function () {
    const gd = document.getElementById('selfsupport-view');
    const canvases = gd ? Array.from(gd.querySelectorAll('canvas')) : [];
    const s = {errors: window.__ss.errors, warnings: window.__ss.warnings,
      rendered: !!(gd && gd._fullLayout && gd._fullData),
      traces: gd && gd._fullData ? gd._fullData.length : 0,
      canvases: canvases.map((c) => [c.width, c.height]),
      legend: gd ? Array.from(gd.querySelectorAll('.legendtext')).map((t) => t.textContent) : [],
      svg_children: gd ? gd.querySelectorAll('.main-svg *').length : 0,
      rects: {}};
    // page boxes of the pieces that must not overlap (viewport pixels: left, top, right, bottom)
    const boxes = {title: '.gtitle', subtitle: '.gtitle-subtitle', button: '.updatemenu-button',
                   subplot_title: '.annotation', axis_title: '.g-xtitle, .g-ytitle', legend: '.legend',
                   xy_ticks: '.xtick, .ytick', scene: '.gl-container > div'};
    for (const [k, sel] of Object.entries(boxes)) {
      s.rects[k] = gd ? Array.from(gd.querySelectorAll(sel)).filter((e) => e.textContent.trim() || k === 'scene')
        .map((e) => { const b = e.getBoundingClientRect(); return [b.left, b.top, b.right, b.bottom]; }) : [];
    }
    document.documentElement.setAttribute('data-ss-status', JSON.stringify(s));
  }, 200);
})();
</script>"""


def _run_chromium(html: Path, shot: Path, profile: Path, *, attempts: int = 2,
                  timeout: float = 90.0) -> tuple[str, str]:
    """Load ``html`` headless, offline; return (DOM after the virtual-time budget, stderr log).

    Chromium runs in its own process group, killed as a whole if it hangs (it has been seen to
    stall on a heavily loaded machine); then it is tried once more with a fresh profile.
    """
    for attempt in range(attempts):
        cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
               "--disable-quic", "--no-first-run", "--disable-background-networking", "--disable-component-update",
               "--disable-sync", "--disable-default-apps", "--disable-extensions",
               f"--user-data-dir={profile}-{attempt}",
               # no network: every request goes to a dead proxy, every host name fails to resolve
               "--proxy-server=http://127.0.0.1:9", "--proxy-bypass-list=<-loopback>",
               "--host-resolver-rules=MAP * ~NOTFOUND",
               "--window-size=1400,900", "--hide-scrollbars", "--virtual-time-budget=3000",
               "--enable-logging=stderr", "--v=0", f"--screenshot={shot}", "--dump-dom", html.as_uri()]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)
        try:
            out, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # our own process group only
            proc.communicate()
            continue
        assert proc.returncode == 0, err[-2000:]
        return out, err
    pytest.fail(f"headless chromium did not finish within {timeout:g} s in {attempts} attempts")


def _overlap(a, b, tol: float = 0.5) -> bool:
    return min(a[2], b[2]) - max(a[0], b[0]) > tol and min(a[3], b[3]) - max(a[1], b[1]) > tol


def _check_layout(rects: dict[str, list], *, width: int, height: int) -> None:
    """The page's text sits inside the window and nothing covers anything else: the title
    and subtitle, the preset buttons, the subplot titles, the 2D axis titles and the legend
    are pairwise disjoint, and the reciprocal panel's tick labels and axis titles stay off the
    3D scenes (they used to be drawn over the network's y axis)."""
    assert rects["title"] and len(rects["button"]) >= 2 and len(rects["subplot_title"]) == 3, rects
    assert len(rects["scene"]) == 2 and len(rects["axis_title"]) == 2, rects
    labels = [(k, r) for k in ("title", "subtitle", "button", "subplot_title", "axis_title", "legend")
              for r in rects[k]]
    for k, r in labels + [("xy_ticks", r) for r in rects["xy_ticks"]]:
        assert -0.5 <= r[0] and r[2] <= width + 0.5 and -0.5 <= r[1] and r[3] <= height + 0.5, (k, r)
    for i, (ka, a) in enumerate(labels):
        for kb, b in labels[i + 1:]:
            assert not _overlap(a, b), f"{ka} {a} overlaps {kb} {b}"
    for k, r in [("axis_title", r) for r in rects["axis_title"]] + [("xy_ticks", r) for r in rects["xy_ticks"]]:
        for scene in rects["scene"]:
            assert not _overlap(r, scene), f"{k} {r} is drawn over a 3D scene {scene}"
    # the buttons sit below the title block, not beside it
    assert min(b[1] for b in rects["button"]) >= max(r[3] for r in rects["title"] + rects["subtitle"])


@pytest.mark.browser
@pytest.mark.skipif(not Path(CHROMIUM).exists(),
                    reason=f"{CHROMIUM} is not installed (Debian package 'chromium'; .ci/run installs it)")
def test_view_renders_offline_in_headless_chromium(solved, tmp_path):
    import matplotlib.image as mpimg

    fig, info = build_view(solved.network, title="pillar vault")
    html = view_html(fig)
    probe = tmp_path / "probe.html"
    probe.write_text(html.replace("<head>", "<head>" + _PROBE, 1), encoding="utf-8")
    shot = tmp_path / "shot.png"
    dom, log = _run_chromium(probe, shot, tmp_path / "profile")

    m = re.search(r'data-ss-status="([^"]*)"', dom)
    assert m, "the page never reported its state (did the scripts run?)"
    status = json.loads(m.group(1).replace("&quot;", '"').replace("&amp;", "&"))
    assert status["errors"] == [], status["errors"]
    assert status["warnings"] == [], status["warnings"]
    assert status["rendered"] and status["traces"] == len(fig.data)
    # the 3D scenes are drawn by WebGL into canvases of real size; the legend lists the layers
    assert any(w > 300 and h > 300 for w, h in status["canvases"]), status["canvases"]
    assert {LAYERS[g] for g in info.layers} <= set(status["legend"])
    assert status["svg_children"] > 50
    assert "WebGL is not supported" not in dom.split("</script>")[-1]
    assert "net::ERR" not in log, "the page tried to load something from the network"
    _check_layout(status["rects"], width=1400, height=900)

    img = mpimg.imread(shot)[..., :3]
    assert img.shape[:2] == (900, 1400)
    drawn = img.min(axis=2) < 0.9
    assert drawn.mean() > 0.05, "screenshot nearly blank"
    # the network's edges in force colours: strongly saturated pixels in the 3D area
    sat = img.max(axis=2) - img.min(axis=2)
    scene = sat[150:850, 50:900]
    assert (scene > 0.5).sum() > 500, "no coloured network drawn in the 3D view"
