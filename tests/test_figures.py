"""Static figures: every kind rendered for a solved generated scene and checked on the image
and on the figure's data (colour scale = force range, reciprocal edges = horizontal forces,
history curves = the solve's records), plus invariances (scaling all forces changes only the
colorbar; scaling one region's forces warms that region and cools the rest)."""
from __future__ import annotations

import io
import json

import matplotlib.image as mpimg  # noqa: E402
import numpy as np
import pytest

from selfsupport.core.errors import InputError  # noqa: E402
from selfsupport.core.loads import SelfWeight  # noqa: E402
from selfsupport.core.mesh import PolyMesh  # noqa: E402
from selfsupport.core.result import Network  # noqa: E402
from selfsupport.core.shapes import make_shape  # noqa: E402
from selfsupport.figures.render import (  # noqa: E402
    _CBAR_RECT,
    _MAIN_RECT,
    FIGURES,
    FigureInput,
    edge_forces,
    make_figure,
    render,
    render_png_bytes,
    signed_distances,
)
from selfsupport.methods.staggered import StaggeredLinearization  # noqa: E402

DPI = 80  # 640 x 480 images: enough for the checks, fast to draw


@pytest.fixture(scope="module")
def solved():
    res = StaggeredLinearization().solve(make_shape("pillar_vault", n_vertices=200), SelfWeight())
    assert res.converged and res.max_relative_error < 1e-9
    return res


def _analysis_available() -> bool:
    try:
        import selfsupport.analysis.airy  # noqa: F401
    except ImportError:
        return False
    return True


def _directions_available() -> bool:
    try:
        import selfsupport.analysis.curvature  # noqa: F401
    except ImportError:
        return False
    return True


needs_airy = pytest.mark.skipif(not _analysis_available(), reason="selfsupport.analysis.airy not importable")
needs_directions = pytest.mark.skipif(not _directions_available(),
                                      reason="selfsupport.analysis.curvature not importable")


def _png(kind: str, inp: FigureInput) -> np.ndarray:
    return mpimg.imread(io.BytesIO(render_png_bytes(kind, inp)), format="png")


def _check_image(img: np.ndarray, inp: FigureInput) -> None:
    w, h = inp.pixel_size
    assert img.shape[:2] == (h, w)
    rgb = img[..., :3]
    assert float(rgb.std()) > 0.05, "image is (nearly) blank"
    assert float((rgb.min(axis=2) < 0.9).mean()) > 0.03, "less than 3% of the pixels are drawn"


def _colorbar_strip(img: np.ndarray) -> np.ndarray:
    """The pixel column through the middle of the colorbar rectangle."""
    h, w = img.shape[:2]
    x0, y0, cw, ch = _CBAR_RECT  # figure fractions, y from the bottom
    col = int(round((x0 + cw / 2) * w))
    top, bottom = int(round((1 - y0 - ch) * h)) + 3, int(round((1 - y0) * h)) - 3
    return img[top:bottom, col, :3]


def _check_gradient(strip: np.ndarray) -> None:
    # a colour ramp: many distinct colours, changing in small steps (not noise, not blank)
    assert len({tuple(np.round(p, 2)) for p in strip}) > 30
    steps = np.abs(np.diff(strip, axis=0)).max(axis=1)
    assert float(np.median(steps)) < 0.05


def _with_weights(net: Network, weights: np.ndarray, loads: np.ndarray | None = None) -> Network:
    return Network(mesh=net.mesh, weights=weights, loads=net.loads if loads is None else loads,
                   supports=net.supports, reference=net.reference, handles=net.handles)


# ------------------------------------------------------------------------------ network
def test_network_figure_default_size_colorbar_and_force_scale(solved, tmp_path):
    net = solved.network
    inp = FigureInput(net, title="pillar vault")
    path = render("network", inp, tmp_path / "net.png")
    img = mpimg.imread(path)
    assert img.shape[:2] == (900, 1200)  # 8 x 6 in at 150 dpi
    _check_image(img, inp)
    _check_gradient(_colorbar_strip(img))
    fig = make_figure("network", inp)
    assert len(fig.axes) == 2  # the 3D view and its colorbar
    f = edge_forces(net)[net.active_edges]
    # independent force magnitudes: |w| times the 3D edge length
    v, e = net.vertices, net.edges[net.active_edges]
    f_ref = np.abs(net.weights[net.active_edges]) * np.sqrt(((v[e[:, 1]] - v[e[:, 0]]) ** 2).sum(axis=1))
    np.testing.assert_allclose(f, f_ref, rtol=1e-12)
    lo, hi = fig.axes[1].get_ylim()  # a vertical colorbar spans vmin..vmax
    assert lo == pytest.approx(f_ref.min(), rel=1e-9) and hi == pytest.approx(f_ref.max(), rel=1e-9)
    # line width grows linearly with the force
    coll = [c for c in fig.axes[0].collections if len(np.atleast_1d(c.get_linewidth())) == len(f)][0]
    lw = np.asarray(coll.get_linewidth())
    fs = np.sort(f)
    slope = np.polyfit(fs, lw, 1)
    np.testing.assert_allclose(np.polyval(slope, fs), lw, atol=1e-9)
    assert slope[0] > 0


def test_network_figure_depends_on_force_ratios_only(solved):
    """Scaling every weight and load by 2 keeps the network in equilibrium and must leave the
    drawing unchanged (widths and colours are relative to the largest force); only the
    colorbar's newtons change."""
    net = solved.network
    twice = _with_weights(net, 2 * net.weights, 2 * net.loads)
    a = _png("network", FigureInput(net, dpi=DPI))
    b = _png("network", FigureInput(twice, dpi=DPI))
    h, w = a.shape[:2]
    plot = (slice(int(0.12 * h), h), slice(0, int((_MAIN_RECT[0] + _MAIN_RECT[2]) * w)))
    np.testing.assert_array_equal(a[plot], b[plot])
    labels = (slice(0, h), slice(int((_CBAR_RECT[0] + _CBAR_RECT[2]) * w) + 2, w))  # colorbar tick labels
    assert np.abs(a[labels] - b[labels]).max() > 0.2
    fa, fb = make_figure("network", FigureInput(net, dpi=DPI)), make_figure("network", FigureInput(twice, dpi=DPI))
    assert fb.axes[1].get_ylim()[1] == pytest.approx(2 * fa.axes[1].get_ylim()[1], rel=1e-12)


def test_network_figure_warms_the_region_whose_forces_grow(solved):
    """Top view (x to the right): tripling the weights of the edges with x > 0 turns that half
    warm (red/yellow) and, the colour scale being relative, cools the other half."""
    net = solved.network
    mid = 0.5 * (net.vertices[net.edges[:, 0]] + net.vertices[net.edges[:, 1]])
    w = net.weights.copy()
    w[mid[:, 0] > 0] *= 3.0
    top = dict(elev=90.0, azim=-90.0, dpi=DPI)
    base = _png("network", FigureInput(net, **top))
    scaled = _png("network", FigureInput(_with_weights(net, w), **top))
    h, wpx = base.shape[:2]
    left, right = int(_MAIN_RECT[0] * wpx), int((_MAIN_RECT[0] + _MAIN_RECT[2]) * wpx)
    rows, cx = slice(int(0.12 * h), h), (left + right) // 2

    def warm(img):
        r, g, b = img[..., 0], img[..., 1], img[..., 2]
        m = (r > 0.6) & (b < 0.35) & (g < 0.75)
        return int(m[rows, left:cx].sum()), int(m[rows, cx:right].sum())

    (bl, br), (sl, sr) = warm(base), warm(scaled)
    # the symmetric vault: both halves equally warm at first
    assert bl > 200 and br > 200 and abs(bl - br) < 0.25 * max(bl, br)
    assert sr >= 0.8 * br and sl < 0.2 * bl


# ------------------------------------------------------------------------------ deviation
def test_signed_distance_to_a_plane_is_the_height():
    xs = np.linspace(-1, 1, 5)
    X, Y = np.meshgrid(xs, xs)
    v = np.c_[X.ravel(), Y.ravel(), np.zeros(25)]
    quads = [[i * 5 + j, i * 5 + j + 1, (i + 1) * 5 + j + 1, (i + 1) * 5 + j] for i in range(4) for j in range(4)]
    plane = PolyMesh.from_faces(v, quads)
    rng = np.random.default_rng(0)
    p = np.c_[rng.uniform(-0.9, 0.9, (40, 2)), rng.uniform(-0.3, 0.3, 40)]
    np.testing.assert_allclose(signed_distances(p, plane), p[:, 2], atol=1e-12)


def _lifted_disk():
    """A flat disk as the reference and the same mesh lifted by h(x, y) = 0.2 x as the network."""
    scene = make_shape("disk", n_vertices=200)
    ref = scene.mesh
    v = ref.vertices.copy()
    v[:, 2] = 0.2 * v[:, 0]
    mesh = ref.with_vertices(v)
    net = Network(mesh=mesh, weights=np.ones(mesh.n_edges), loads=-np.ones(mesh.n_vertices),
                  supports=scene.supports, reference=ref)
    return net, v[:, 2]


def test_deviation_figure_scale_and_hull_markers():
    from selfsupport.methods.base import HULL_TOL

    net, height = _lifted_disk()
    t = 0.2  # hull ± 0.1: the vertices with |0.2 x| > 0.1, i.e. |x| > 0.5, are outside
    inp = FigureInput(net, thickness=t, dpi=DPI)
    fig = make_figure("deviation", inp)
    assert len(fig.axes) == 2
    assert fig.axes[1].get_ylim() == pytest.approx((-t / 2, t / 2))
    crosses = [c for c in fig.axes[0].collections if c.get_gid() == "outside-hull"]
    # the hull's one definition (selfsupport.methods.base.hull_excess): free vertices beyond t/2
    # by more than its tolerance (1% of t/2); supports are held by the ground
    outside = (np.abs(height) > t / 2 * (1 + HULL_TOL)) & ~np.asarray(net.supports)
    assert len(crosses) == 1 and len(crosses[0]._offsets3d[0]) == int(outside.sum()) > 0
    np.testing.assert_allclose(np.sort(np.asarray(crosses[0]._offsets3d[0])), np.sort(net.vertices[outside, 0]))
    img = _png("deviation", inp)
    _check_image(img, inp)
    _check_gradient(_colorbar_strip(img))
    # without a thickness the scale is the largest distance
    fig2 = make_figure("deviation", FigureInput(net, dpi=DPI))
    assert fig2.axes[1].get_ylim()[1] == pytest.approx(np.abs(height).max(), rel=1e-6)


def test_deviation_needs_a_reference(solved):
    net = solved.network
    bare = Network(mesh=net.mesh, weights=net.weights, loads=net.loads, supports=net.supports)
    with pytest.raises(InputError, match="reference"):
        make_figure("deviation", FigureInput(bare))


# ------------------------------------------------------------------------------ history
def test_history_figure_plots_the_records(solved):
    inp = FigureInput(solved.network, history=solved.history, dpi=DPI)
    fig = make_figure("history", inp)
    assert len(fig.axes) == 2  # errors, penalties
    by_label = {ln.get_label(): ln for ax in fig.axes for ln in ax.get_lines()}
    hist = solved.history
    E = np.array([r.get("E", np.nan) for r in hist], float)
    np.testing.assert_allclose(by_label["fit error E (relative)"].get_ydata(), E)
    alpha = np.array([r.get("alpha", np.nan) for r in hist], float)
    np.testing.assert_allclose(by_label["α (reference penalty)"].get_ydata(), alpha)
    # the final polish record carries the network's own max relative error
    mre = by_label["max relative error"].get_ydata()
    assert mre[-1] == pytest.approx(solved.max_relative_error, rel=1e-6)
    assert all(ax.get_yscale() == "log" for ax in fig.axes)
    _check_image(_png("history", inp), inp)


def test_history_figure_needs_records(solved):
    with pytest.raises(InputError, match="history"):
        make_figure("history", FigureInput(solved.network))


# ------------------------------------------------------------------------------ analysis
@needs_airy
def test_reciprocal_figure_edges_are_the_horizontal_forces(solved):
    net = solved.network
    inp = FigureInput(net, dpi=DPI)
    fig = make_figure("reciprocal", inp)
    assert len(fig.axes) == 2
    seg = np.asarray(fig.axes[0].collections[0].get_segments())
    drawn = np.sort(np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1))
    # a dual edge is w_ij J e'_ij: its length is |w| times the top-view edge length
    ef = net.mesh.edge_faces
    interior = (ef >= 0).all(axis=1) & net.active_edges  # support-support edges carry nothing
    e = net.edges[interior]
    d = net.vertices[e[:, 1], :2] - net.vertices[e[:, 0], :2]
    expected = np.sort(np.abs(net.weights[interior]) * np.linalg.norm(d, axis=1))
    np.testing.assert_allclose(drawn, expected, rtol=1e-6, atol=1e-9 * expected.max())
    img = _png("reciprocal", inp)
    _check_image(img, inp)
    _check_gradient(_colorbar_strip(img))


@needs_airy
def test_airy_figure(solved):
    from selfsupport.figures.render import airy_of

    inp = FigureInput(solved.network, dpi=DPI)
    phi = np.asarray(airy_of(solved.network).phi)
    fig = make_figure("airy", inp)
    assert len(fig.axes) == 2
    assert fig.axes[1].get_ylim() == pytest.approx((phi.min(), phi.max()), rel=1e-9)
    img = _png("airy", inp)
    _check_image(img, inp)
    _check_gradient(_colorbar_strip(img))


@needs_directions
def test_directions_figure_draws_the_conjugate_principal_directions(solved):
    from selfsupport.figures.render import directions_of

    net = solved.network
    curv = directions_of(net)
    inp = FigureInput(net, dpi=DPI, directions=curv)
    fig = make_figure("directions", inp)
    assert len(fig.axes) == 2
    ax = fig.axes[0]
    D = curv.principal_directions
    at = np.flatnonzero(~net.supports & np.isfinite(D).all(axis=(1, 2)))
    assert at.size > 0.5 * (~net.supports).sum()
    crosses = [c for c in ax.collections if c.get_label().startswith("direction of")]
    assert len(crosses) == 2
    drawn = []
    for c in crosses:
        seg = np.asarray(c.get_segments())
        assert len(seg) == len(at)
        np.testing.assert_allclose(0.5 * (seg[:, 0] + seg[:, 1]), net.vertices[at, :2], atol=1e-12)
        d = seg[:, 1] - seg[:, 0]
        drawn.append(d / np.linalg.norm(d, axis=1, keepdims=True))
    # eigenvectors of (∇²φ)⁻¹∇²s are conjugate with respect to ∇²φ: d1ᵀ ∇²φ d2 = 0
    Hp = curv.hessian_phi[at]
    conj = np.einsum("ni,nij,nj->n", drawn[0], Hp, drawn[1])
    scale = np.abs(Hp).max(axis=(1, 2))
    assert np.all(np.abs(conj) <= 1e-8 * scale)
    _check_image(_png("directions", inp), inp)


# ------------------------------------------------------------------------------ registry, CLI, report
def test_registry_and_errors(solved, tmp_path):
    from selfsupport.cli.figures import FIGURE_KINDS

    assert set(FIGURES) == set(FIGURE_KINDS) == {"network", "deviation", "airy", "reciprocal", "directions",
                                                 "history", "reactions"}
    with pytest.raises(InputError, match="unknown figure kind"):
        make_figure("nope", FigureInput(solved.network))
    with pytest.raises(InputError, match="PNG"):
        render("network", FigureInput(solved.network), tmp_path / "x.jpg")
    with pytest.raises(InputError, match="thickness"):
        FigureInput(solved.network, thickness=-1.0)


def test_cli_render(solved, tmp_path, capsys):
    from selfsupport.cli import main
    from selfsupport.io import write_network

    net_path = tmp_path / "net.json"
    write_network(net_path, solved, scene={"name": "pv"})
    out = tmp_path / "hist.png"
    assert main(["render", str(net_path), "--out", str(out), "--what", "history", "--dpi", "50"]) == 0
    img = mpimg.imread(out)
    assert img.shape[:2] == (300, 400)
    assert "history figure" in capsys.readouterr().out
    # the history comes from the file: same curves as from the result
    doc = json.loads(net_path.read_text())
    assert len(doc["history"]) == len(solved.history)
    assert main(["render", str(net_path), "--out", str(tmp_path / "a.png"), "--what", "bogus"]) == 2
    assert main(["render", str(tmp_path / "missing.json"), "--out", str(tmp_path / "b.png")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert not (tmp_path / "b.png").exists()


def test_write_report(solved, tmp_path):
    from selfsupport.figures.report import REPORT_KINDS, write_report

    files = write_report(solved, tmp_path / "rep", name="pillar vault", dpi=40,
                         kinds=("network", "deviation", "history"), view=False)
    assert set(files.figures) == {"network", "deviation", "history"} and not files.skipped
    for kind, p in files.figures.items():
        assert mpimg.imread(p).shape[:2] == (240, 320)
    assert "![network](network.png)" in files.markdown()
    assert set(REPORT_KINDS) <= set(FIGURES)
    # a network without reference or history: those figures are skipped with the reason, the rest written
    net = solved.network
    bare = Network(mesh=net.mesh, weights=net.weights, loads=net.loads, supports=net.supports)
    files = write_report(bare, tmp_path / "bare", dpi=40, kinds=("network", "deviation", "history"), view=False)
    assert set(files.figures) == {"network"}
    assert "reference" in files.skipped["deviation"] and "history" in files.skipped["history"]


# ------------------------------------------------------------------------------ layout and units
def _drawn_texts(fig, renderer) -> list[tuple[str, object]]:
    """(role, artist) of every non-empty text the figure draws.

    Tick labels count only for ticks inside the axis' view interval: 3D axes keep label
    artists for the ticks outside it, never drawn, at meaningless positions.
    """
    out = []

    def add(role, t):
        if t is not None and t.get_visible() and t.get_text().strip():
            out.append((role, t))

    title = fig.get_suptitle()
    for t in fig.texts:
        add("suptitle" if t.get_text() == title else "figure text", t)
    for ax in fig.axes:
        add("axes title", ax.title)
        for t in ax.texts:
            add("axes text", t)
        if ax.get_legend() is not None:
            for t in ax.get_legend().get_texts():
                add("legend", t)
        for axis in (ax.xaxis, ax.yaxis, getattr(ax, "zaxis", None)):
            if axis is None or not axis.get_visible():
                continue
            add("axis label", axis.label)
            add("offset text", axis.get_offset_text())
            lo, hi = sorted(axis.get_view_interval())
            eps = 1e-9 * max(hi - lo, 1e-300)
            for tick in axis.get_major_ticks():
                if tick.get_loc() is not None and lo - eps <= tick.get_loc() <= hi + eps:
                    add("tick label", tick.label1)
                    add("tick label", tick.label2)
    return out


def _available_kinds() -> list[str]:
    kinds = ["network", "deviation", "history", "reciprocal", "airy", "directions", "reactions"]
    if not _analysis_available():
        kinds = [k for k in kinds if k not in ("airy", "reciprocal", "directions")]
    elif not _directions_available():
        kinds.remove("directions")
    return kinds


LONG_TITLE = ("a_scene_read_from/a/rather/deep/directory/of/the/user/lilium-pillar-refined-variant-3.sss "
              "(staggered, converged)")


@pytest.mark.parametrize("title", ["pillar_vault(n=25) (staggered, converged)", LONG_TITLE])
@pytest.mark.parametrize("kind", _available_kinds())
def test_every_text_is_on_the_canvas_and_the_title_covers_nothing(solved, kind, title):
    """A long title must not run off the PNG: every drawn text lies
    inside the canvas, and the title overlaps neither another text nor any axes' drawn extent
    (its labels, ticks and legend included), for a usual and for a very long scene name."""
    inp = FigureInput(solved.network, history=solved.history, title=title, thickness=0.1, dpi=DPI)
    fig = make_figure(kind, inp)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    width, height = fig.bbox.width, fig.bbox.height
    texts = _drawn_texts(fig, renderer)
    roles = [r for r, _ in texts]
    assert roles.count("suptitle") == 1 and "axis label" in roles and "tick label" in roles
    for role, t in texts:
        bb = t.get_window_extent(renderer)
        assert bb.x0 >= -0.5 and bb.y0 >= -0.5 and bb.x1 <= width + 0.5 and bb.y1 <= height + 0.5, \
            f"{kind}: {role} {t.get_text()!r} at {bb.extents} leaves the {width:g} x {height:g} canvas"
    sup = next(t for r, t in texts if r == "suptitle").get_window_extent(renderer)
    for role, t in texts:
        if role != "suptitle":
            assert not sup.overlaps(t.get_window_extent(renderer)), f"{kind}: the title covers {role} {t.get_text()!r}"
    for ax in fig.axes:
        assert ax.get_tightbbox(renderer).y1 <= sup.y0 + 0.5, f"{kind}: the title covers an axes"


def test_the_same_figure_is_the_same_png(solved):
    """The title fitting measures text with Agg: deterministic, the PNG is byte-identical."""
    inp = FigureInput(solved.network, history=solved.history, title=LONG_TITLE, thickness=0.1, dpi=DPI)
    assert render_png_bytes("deviation", inp) == render_png_bytes("deviation", inp)


def test_unit_prefix_is_chosen_once_per_quantity():
    from selfsupport.figures.render import Unit

    assert Unit.for_magnitude(52_000.0, "N·m") == Unit(1e3, "kN·m")
    assert Unit.for_magnitude(650.0, "N·m") == Unit(1.0, "N·m")
    assert Unit.for_magnitude(0.05, "m") == Unit(1e-3, "mm")
    assert Unit.for_magnitude(0.0, "N") == Unit(1.0, "N")
    assert Unit.for_values([-3.2e6, 1.0], "N") == Unit(1e6, "MN")
    fmt = Unit(1e3, "kN").formatter()
    assert [fmt(v) for v in (-20_000.0, 0.0, -0.0, 39_999.999999999, 2_500.0)] == ["−20", "0", "0", "40", "2.5"]


def _tick_texts(axis) -> list[str]:
    lo, hi = sorted(axis.get_view_interval())
    return [t.label1.get_text() for t in axis.get_major_ticks() if lo <= t.get_loc() <= hi]


@needs_airy
def test_airy_figure_writes_phi_in_one_unit(solved):
    """airy.png must not label its φ axis N·m with ticks 20000, 40000 next to a colorbar
    in kN·m: the φ axis, the colorbar and the units note name one unit, tick labels are
    plain numbers in it, and a tick reads its location divided by the unit's scale."""
    import re

    from selfsupport.figures.render import airy_of

    net = solved.network
    peak = float(np.abs(airy_of(net).phi).max())
    # φ is linear in the weights: the same network with all forces scaled so that |φ| peaks
    # at 500 N·m, and at 50 kN·m (the demo's range, which showed both units)
    cases = [(_with_weights(net, k * net.weights, k * net.loads), symbol)
             for k, symbol in ((500.0 / peak, "N·m"), (5e4 / peak, "kN·m"))]
    for net, symbol in cases:
        fig = make_figure("airy", FigureInput(net, dpi=DPI))
        fig.canvas.draw()
        ax, cax = fig.axes
        labels = [ax.get_zlabel(), cax.get_ylabel()] + [t.get_text() for t in fig.texts if "units" in t.get_text()]
        assert len(labels) == 3
        units = {u for text in labels for u in re.findall(r"[kMGmµ]?N·m", text)}
        assert units == {symbol}, labels
        scale = {"N·m": 1.0, "kN·m": 1e3}[symbol]
        for axis in (ax.zaxis, cax.yaxis):
            lo, hi = sorted(axis.get_view_interval())
            ticks = [t for t in axis.get_major_ticks() if lo <= t.get_loc() <= hi]
            assert len(ticks) >= 2
            for t in ticks:
                text = t.label1.get_text()
                assert re.fullmatch(r"−?\d+(\.\d+)?", text), text  # no prefix, no unit in a tick
                assert float(text.replace("−", "-")) * scale == pytest.approx(t.get_loc(), rel=1e-6, abs=1e-9)


@needs_airy
def test_reciprocal_figure_writes_forces_in_one_unit(solved):
    fig = make_figure("reciprocal", FigureInput(solved.network, dpi=DPI))
    fig.canvas.draw()
    ax, cax = fig.axes
    import re

    units = {u for text in (ax.get_xlabel(), ax.get_ylabel(), cax.get_ylabel()) for u in re.findall(r"\[(.*?)\]", text)}
    assert len(units) == 1 and units <= {"N", "kN", "MN"}
    assert all(re.fullmatch(r"−?\d+(\.\d+)?", s) for s in _tick_texts(ax.xaxis) + _tick_texts(cax.yaxis))
