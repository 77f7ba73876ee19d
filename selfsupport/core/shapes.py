"""Built-in reference shapes, generated from a few parameters (no data files).

Every factory returns a :class:`~selfsupport.core.scene.Scene` (z up, metres) whose mesh is a
valid, consistently oriented manifold height field: faces run counter-clockwise seen from
above, so every face normal points up. All generation is vectorised numpy and
deterministic; 64k vertices build in a few tens of milliseconds.

* ``disk(n_rings)``, ``dome(rings)``, ``concave_disk(rings)``: ``1 + 3 n (n + 1)``
  vertices (n rings), supported on the boundary ring.
* ``meridian_dome(parallels, meridians)``: the same cap on a meridian × parallel grid
  (``1 + parallels · meridians`` vertices; triangles at the crown, quads elsewhere), its
  edges along the meridians and the hoops; not in :data:`SHAPES`.
* ``barrel_vault(nx, ny)``: ``(nx + 1)(ny + 1)`` vertices (nx, ny cells), supported on the
  whole boundary by default (see its docstring).
* ``cross_vault(n)`` (n even) and ``pillar_vault(n)``: ``(n + 1)²`` vertices; the cross
  vault is supported on its boundary, the pillar vault on four corner patches.

The disk-like shapes share one triangulation of the unit disk: rings ``k = 0..n`` at radius
``k / n`` carrying ``6k`` equally spaced points, zipped ring to ring in the order of the
chords' angular midpoints. That order is exactly the Delaunay triangulation of the point
set (all triangles are acute, minimum angle ~44°), so the cotangent (Voronoi-dual /
primal length) weights of §2.5 are non-negative on the flat disk.

:func:`make_shape` picks the resolution for a target vertex count (within 4% from 1,000
vertices up, 13% from 150 up), for scaling studies:

>>> make_shape("dome", n_vertices=4000).mesh.n_vertices
3997
>>> sorted(SHAPES)[:3]
['barrel_vault', 'concave_disk', 'cross_vault']
"""
from __future__ import annotations

import inspect
import math
from typing import Callable

import numpy as np

from selfsupport.core.errors import InputError
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.scene import Scene

__all__ = ["SHAPES", "make_shape", "disk", "disk_points", "dome", "meridian_dome", "concave_disk", "barrel_vault",
           "cross_vault", "pillar_vault"]


# ---------------------------------------------------------------------------- checks
def _positive(name: str, value: float) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise InputError(f"{name} must be a positive finite number, got {value!r}")
    return v


def _count(name: str, value: int, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or int(value) < minimum:
        raise InputError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


# ---------------------------------------------------------------------------- mesh helpers
def _tri_mesh(vertices: np.ndarray, tris: np.ndarray) -> PolyMesh:
    tris = np.asarray(tris, dtype=np.int64)
    return PolyMesh(vertices, tris.ravel(), np.arange(0, 3 * len(tris) + 1, 3))


def _quad_mesh(vertices: np.ndarray, quads: np.ndarray) -> PolyMesh:
    quads = np.asarray(quads, dtype=np.int64)
    return PolyMesh(vertices, quads.ravel(), np.arange(0, 4 * len(quads) + 1, 4))


def _ring_disk(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit-disk ring triangulation: ``(rho, theta, triangles)``.

    Ring ``k`` (radius ``k/n``) holds ``6k`` points at angles ``2π j / 6k`` (ring 0 is the
    centre). The strip between rings ``k-1`` and ``k`` is zipped: each chord of either ring
    becomes one triangle whose apex is the current point of the other ring, the chords
    taken in the order of their angular midpoints (ties: inner chord first). For points
    on two concentric circles four points are co-circular exactly when the two chords have
    the same midpoint angle, so this order is the Delaunay one. Triangles are CCW.
    """
    k = np.arange(n + 1)
    counts = np.where(k == 0, 1, 6 * k)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    ring = np.repeat(k, counts)
    j = np.arange(int(counts.sum())) - starts[ring]
    theta = 2.0 * np.pi * j / counts[ring]
    rho = ring / n

    # chord events of strip p (inner ring p-1, outer ring p), p = 1..n; chord j -> j+1
    inner = (ring < n) & (ring >= 1)          # the centre (ring 0) has no chords
    p_in, j_in = ring[inner] + 1, j[inner]
    key_in = (j_in + 0.5) / counts[p_in - 1]
    outer = ring >= 1
    p_out, j_out = ring[outer], j[outer]
    key_out = (j_out + 0.5) / counts[p_out]
    strip = np.concatenate([p_in, p_out])
    key = np.concatenate([key_in, key_out])
    kind = np.concatenate([np.zeros(len(p_in), np.int64), np.ones(len(p_out), np.int64)])
    order = np.lexsort((kind, key, strip))
    strip, kind = strip[order], kind[order]

    is_in = (kind == 0).astype(np.int64)
    is_out = 1 - is_in
    before_in = np.cumsum(is_in) - is_in
    before_out = np.cumsum(is_out) - is_out
    first = np.searchsorted(strip, strip, side="left")
    c_in = before_in - before_in[first]       # inner chords already taken in this strip
    c_out = before_out - before_out[first]
    m, mm = counts[strip - 1], counts[strip]
    in_cur = starts[strip - 1] + c_in % m
    in_new = starts[strip - 1] + (c_in + 1) % m
    out_cur = starts[strip] + c_out % mm
    out_new = starts[strip] + (c_out + 1) % mm
    tris = np.where((kind == 0)[:, None],
                    np.stack([in_cur, out_cur, in_new], axis=1),
                    np.stack([out_cur, out_new, in_cur], axis=1))
    return rho, theta, tris


def _rings_for(n_vertices: int) -> int:
    """Ring count n with ``1 + 3 n (n + 1)`` closest to ``n_vertices``."""
    x = (-3.0 + math.sqrt(max(12.0 * n_vertices - 3.0, 9.0))) / 6.0
    cands = {max(1, math.floor(x)), max(1, math.ceil(x))}
    return min(cands, key=lambda r: abs(1 + 3 * r * (r + 1) - n_vertices))


def _grid_triangles(nu: int, nv: int, radial: bool) -> np.ndarray:
    """Triangles of an ``nu x nv`` cell grid (vertex ``j (nu+1) + i``), CCW, mirror symmetric.

    Each cell is split along the diagonal that points to the grid centre (``radial``: the
    diagonals of the plan square lie on mesh edges) or across it.
    """
    i, jj = np.meshgrid(np.arange(nu), np.arange(nv), indexing="xy")
    i, jj = i.ravel(), jj.ravel()
    a = jj * (nu + 1) + i
    b, c, d = a + 1, a + nu + 2, a + nu + 1
    sx = np.sign(2 * i + 1 - nu)
    sy = np.sign(2 * jj + 1 - nv)
    main = (sx * sy >= 0) if radial else (sx * sy < 0)
    t_main = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    t_anti = np.concatenate([np.stack([a, b, d], 1), np.stack([b, c, d], 1)])
    return np.where(np.concatenate([main, main])[:, None], t_main, t_anti)


def _grid_quads(nu: int, nv: int) -> np.ndarray:
    i, jj = np.meshgrid(np.arange(nu), np.arange(nv), indexing="xy")
    a = (jj * (nu + 1) + i).ravel()
    return np.stack([a, a + 1, a + nu + 2, a + nu + 1], axis=1)


def _catenary_parameter(half_span: float, rise: float) -> float:
    """``c`` with ``c (cosh(a/c) - 1) = rise``: the catenary ``z = c (cosh(a/c) - cosh(x/c))``."""
    from scipy.optimize import brentq  # (0.1 s to import: a solve of a file does not need it)

    target = rise / half_span
    t = brentq(lambda t: (math.cosh(t) - 1.0) / t - target, 1e-12, 700.0, xtol=1e-14, rtol=1e-14)
    return half_span / t


def _catenary_height(x: np.ndarray, half_span: float, c: float) -> np.ndarray:
    return c * (np.cosh(half_span / c) - np.cosh(x / c))


def _catenary_arclength_positions(u: np.ndarray, half_span: float, c: float) -> np.ndarray:
    """Plan positions ``x`` in [-a, a] whose catenary arc length is uniform in ``u`` in [-1, 1]."""
    return c * np.arcsinh(u * np.sinh(half_span / c))


def _scene(mesh: PolyMesh, supports: np.ndarray, name: str, **meta) -> Scene:
    return Scene(mesh=mesh, supports=supports, name=name, meta={"shape": name.split("(")[0], **meta})


# ---------------------------------------------------------------------------- disks
def disk_points(n_rings: int, radius: float = 1.0) -> np.ndarray:
    """The ``(1 + 3 n (n+1), 2)`` plan points of :func:`disk`: ring ``k`` at radius ``k R / n``
    with ``6k`` equally spaced points (spacing ~``R / n`` both ways), centre first."""
    n = _count("n_rings", n_rings, 1)
    radius = _positive("radius", radius)
    k = np.arange(n + 1)
    counts = np.where(k == 0, 1, 6 * k)
    ring = np.repeat(k, counts)
    j = np.arange(int(counts.sum())) - np.concatenate([[0], np.cumsum(counts)[:-1]])[ring]
    theta = 2.0 * np.pi * j / counts[ring]
    r = radius * ring / n
    return np.stack([r * np.cos(theta), r * np.sin(theta)], axis=1)


def disk(n_rings: int = 18, radius: float = 1.0, z: float = 0.0) -> Scene:
    """Flat triangulated disk at height ``z``, supported on its boundary.

    The points are :func:`disk_points`; the triangulation is their Delaunay triangulation
    (all triangles acute), so the §2.5 construction with φ = ½(x² + y²) gives positive
    weights. The analytic test solution is ``s = (F/4)(r² − R²)``.
    """
    n = _count("n_rings", n_rings, 1)
    radius = _positive("radius", radius)
    z = float(z)
    if not math.isfinite(z):
        raise InputError(f"z must be finite, got {z!r}")
    rho, theta, tris = _ring_disk(n)
    r = radius * rho
    v = np.stack([r * np.cos(theta), r * np.sin(theta), np.full_like(r, z)], axis=1)
    return _scene(_tri_mesh(v, tris), rho >= 1.0, f"disk(n_rings={n})",
                  params={"n_rings": n, "radius": radius, "z": z})


def _cap(radius: float, height: float) -> tuple[float, float, float, float]:
    """A spherical cap's checked plan radius and height, its sphere radius R and its opening angle."""
    radius = _positive("radius", radius)
    height = _positive("height", height)
    if height > radius:
        raise InputError(f"dome height {height} exceeds the plan radius {radius}: the cap would overhang; "
                         "use height <= radius")
    R = (radius ** 2 + height ** 2) / (2.0 * height)
    return radius, height, R, math.atan2(radius, R - height)


def dome(rings: int = 18, radius: float = 5.0, height: float = 2.5) -> Scene:
    """Spherical-cap dome over a disk of plan radius ``radius``, apex at ``height``.

    Sphere radius ``R = (radius² + height²) / (2 height)``; ``height <= radius`` (a cap
    beyond the hemisphere overhangs and has no top view). The ring triangulation of
    :func:`disk` is mapped onto the cap with rings equally spaced in arc length along the
    meridians (azimuthal-equidistant), so triangles are near-equilateral on the surface.
    Supports: the outer ring. ``meta['area']`` is the exact cap area ``2 π R height``.
    """
    n = _count("rings", rings, 1)
    radius, height, R, psi_max = _cap(radius, height)
    rho, theta, tris = _ring_disk(n)
    psi = psi_max * rho
    r = R * np.sin(psi)
    v = np.stack([r * np.cos(theta), r * np.sin(theta), R * np.cos(psi) - (R - height)], axis=1)
    v[rho >= 1.0, 2] = 0.0
    return _scene(_tri_mesh(v, tris), rho >= 1.0, f"dome(rings={n})",
                  params={"rings": n, "radius": radius, "height": height},
                  sphere_radius=R, area=2.0 * math.pi * R * height)


def meridian_dome(parallels: int = 16, meridians: int = 32, radius: float = 5.0, height: float = 2.5) -> Scene:
    """The spherical cap of :func:`dome` on a meridian × parallel grid: the crown vertex and
    ``parallels`` rings of ``meridians`` vertices, equally spaced in arc length along the
    meridians, joined by triangles at the crown and planar quads (isosceles trapezoids)
    elsewhere, so that every edge runs along a meridian or a hoop. Supports: the outer ring.
    """
    n = _count("parallels", parallels, 1)
    m = _count("meridians", meridians, 3)
    radius, height, R, psi_max = _cap(radius, height)
    psi = psi_max * np.repeat(np.arange(1, n + 1) / n, m)
    theta = np.tile(2.0 * np.pi * np.arange(m) / m, n)
    r = R * np.sin(psi)
    v = np.vstack([[0.0, 0.0, height],
                   np.stack([r * np.cos(theta), r * np.sin(theta), R * np.cos(psi) - (R - height)], axis=1)])
    v[-m:, 2] = 0.0
    j = np.arange(m)
    crown = np.stack([np.zeros(m, np.int64), 1 + j, 1 + (j + 1) % m], axis=1)
    k = np.repeat(np.arange(n - 1), m)
    jj = np.tile(j, n - 1)
    quads = np.stack([1 + k * m + jj, 1 + (k + 1) * m + jj, 1 + (k + 1) * m + (jj + 1) % m, 1 + k * m + (jj + 1) % m],
                     axis=1)
    faces = np.concatenate([crown.ravel(), quads.ravel()])
    offsets = np.r_[np.arange(0, 3 * m + 1, 3), 3 * m + 4 * np.arange(1, len(quads) + 1)]
    supports = np.zeros(len(v), dtype=bool)
    supports[-m:] = True
    return _scene(PolyMesh(v, faces, offsets), supports, f"meridian_dome(parallels={n}, meridians={m})",
                  params={"parallels": n, "meridians": m, "radius": radius, "height": height},
                  sphere_radius=R, area=2.0 * math.pi * R * height)


def concave_disk(rings: int = 18, radius: float = 5.0, height: float = 2.0, dent: float = 0.6,
                 dent_width: float = 0.25, wobble: float = 0.1) -> Scene:
    """A freeform dome whose centre is pushed down into a dip: it cannot stand as it is.

    ``z = height (1 − ρ²) − dent g(ρ) + wobble·height·b(ρ, θ)`` with ``ρ = r / radius``,
    ``g`` a Gaussian of width ``dent_width`` (``g(0) = 1``, ``g(1) = 0``) and ``b`` a
    three-lobed bump (``∝ ρ³(1 − ρ²) cos 3θ``, peak 1) that makes the shape non-axisymmetric
    and vanishes at the centre and on the boundary (which stays at z = 0). The centre
    vertex lies ``dent`` below the undented apex and lower than all its neighbours, so a
    solver has to move it. Supports: the outer ring. Mesh: the :func:`disk` triangulation
    (``rings >= 3``; a dent too shallow to make the centre a dip raises :class:`InputError`).
    """
    n = _count("rings", rings, 3)
    radius = _positive("radius", radius)
    height = _positive("height", height)
    dent = _positive("dent", dent)
    sigma = _positive("dent_width", dent_width)
    wobble = float(wobble)
    if not math.isfinite(wobble):
        raise InputError(f"wobble must be finite, got {wobble!r}")
    rho, theta, tris = _ring_disk(n)
    tail = math.exp(-1.0 / sigma ** 2)
    g = (np.exp(-(rho / sigma) ** 2) - tail) / (1.0 - tail)
    bump = rho ** 3 * (1.0 - rho ** 2) * np.cos(3.0 * theta) / (0.6 ** 1.5 * 0.4)
    z = height * (1.0 - rho ** 2) - dent * g + wobble * height * bump
    z[rho >= 1.0] = 0.0
    r = radius * rho
    v = np.stack([r * np.cos(theta), r * np.sin(theta), z], axis=1)
    if not np.all(z[1:7] > z[0]):
        raise InputError(f"dent={dent} is too shallow for dent_width={sigma} at rings={n}: the centre is not "
                         f"lower than its neighbours; use dent > {height * sigma ** 2:.3g} or more rings")
    return _scene(_tri_mesh(v, tris), rho >= 1.0, f"concave_disk(rings={n})",
                  params={"rings": n, "radius": radius, "height": height, "dent": dent,
                          "dent_width": sigma, "wobble": wobble}, centre_vertex=0)


# ---------------------------------------------------------------------------- vaults
def barrel_vault(nx: int = 26, ny: int = 36, span: float = 6.0, length: float = 10.0, rise: float = 2.0,
                 quads: bool = True, gables_supported: bool = True) -> Scene:
    """Catenary barrel vault: ``span`` across x (``nx`` cells), ``length`` along y (``ny`` cells).

    The cross-section is the catenary of the given ``rise``, sampled at equal arc length, so
    cells are near-square on the surface. ``quads=False`` splits every quad into two
    triangles (diagonals mirror-symmetric about the centre lines).

    Supports: the two springing lines (long edges) **and**, by default, the two gable
    ends, i.e. the whole boundary. A free boundary vertex can only be balanced by
    compressive forces where the boundary polygon bends inward in plan; a straight free
    gable has nothing to push against, so with ``gables_supported=False`` (springing lines
    only) no compressive network exists with weights bounded away from zero: use that
    variant only to exercise infeasibility reporting.
    """
    nx = _count("nx", nx, 2)
    ny = _count("ny", ny, 2)
    span, length, rise = _positive("span", span), _positive("length", length), _positive("rise", rise)
    a = span / 2.0
    c = _catenary_parameter(a, rise)
    xs = _catenary_arclength_positions(np.linspace(-1.0, 1.0, nx + 1), a, c)
    xs[0], xs[-1] = -a, a
    zs = _catenary_height(xs, a, c)
    zs[0] = zs[-1] = 0.0
    ys = np.linspace(-length / 2.0, length / 2.0, ny + 1)
    X, Y = np.meshgrid(xs, ys, indexing="xy")
    Z = np.broadcast_to(zs, X.shape)
    v = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    i, j = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), indexing="xy")
    i, j = i.ravel(), j.ravel()
    supports = (i == 0) | (i == nx)
    if gables_supported:
        supports |= (j == 0) | (j == ny)
    mesh = _quad_mesh(v, _grid_quads(nx, ny)) if quads else _tri_mesh(v, _grid_triangles(nx, ny, radial=True))
    return _scene(mesh, supports, f"barrel_vault(nx={nx}, ny={ny})",
                  params={"nx": nx, "ny": ny, "span": span, "length": length, "rise": rise, "quads": bool(quads),
                          "gables_supported": bool(gables_supported)}, catenary_parameter=c)


def cross_vault(n: int = 32, span: float = 6.0, rise: float = 2.5) -> Scene:
    """Groin (cross) vault over a ``span`` x ``span`` square: ``z = max(p(x), p(y))``.

    ``p`` is the catenary of the given ``rise`` over the span, so the surface is the union
    of two perpendicular barrel vaults, with valley creases (the groins) along the plan
    diagonals. The triangle mesh has ``n`` cells per side (``n`` even) with the groins on
    mesh edges, on a grid uniform in plan (the triangles next to the steep
    groins near the corners are the thinnest, ~25° at the defaults). Supports: the whole boundary (the four boundary arches are
    straight in plan and could not stand free, see :func:`barrel_vault`).
    """
    n = _count("n", n, 2)
    if n % 2:
        raise InputError(f"cross_vault needs an even n so that the groins lie on mesh edges, got n={n}")
    span, rise = _positive("span", span), _positive("rise", rise)
    a = span / 2.0
    c = _catenary_parameter(a, rise)
    s = np.linspace(-a, a, n + 1)
    s[n // 2] = 0.0
    X, Y = np.meshgrid(s, s, indexing="xy")
    Z = np.maximum(_catenary_height(X, a, c), _catenary_height(Y, a, c))
    v = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="xy")
    i, j = i.ravel(), j.ravel()
    supports = (i == 0) | (i == n) | (j == 0) | (j == n)
    return _scene(_tri_mesh(v, _grid_triangles(n, n, radial=True)), supports, f"cross_vault(n={n})",
                  params={"n": n, "span": span, "rise": rise}, catenary_parameter=c)


def pillar_vault(n: int = 32, span: float = 8.0, rise: float = 2.0, pillar_radius_frac: float = 0.1,
                 bulge: float = 0.1) -> Scene:
    """A vault on four pillars at the corners of a ``span`` x ``span`` square.

    Plan: the square with its four sides replaced by circular arcs bulging towards the
    centre by ``bulge * span`` (sagitta), so every free boundary vertex turns inward
    (concave in plan) and can be balanced by compression. Height: the paraboloid
    ``rise (1 − r² / r_c²)`` that vanishes at the corners (``r_c`` the corner radius); the
    free edges are arches rising between the pillars. Supports: the vertices within
    ``pillar_radius_frac * span`` of a corner, and at least the corner cell's four vertices.

    Mesh: the ``n`` x ``n`` grid mapped onto the plan by the bilinearly blended (Coons)
    map ``(a u + u d(a v), a v + v d(a u))``, ``d`` the arcs' inward offset, split into
    triangles along the short diagonals at the (acute) corners.
    """
    n = _count("n", n, 4)
    span, rise = _positive("span", span), _positive("rise", rise)
    frac = _positive("pillar_radius_frac", pillar_radius_frac)
    bulge = _positive("bulge", bulge)
    if bulge > 0.15:
        raise InputError(f"bulge={bulge} is too large: the plan corners would become too sharp; use bulge <= 0.15")
    if frac >= 0.5:
        raise InputError(f"pillar_radius_frac={frac} makes the pillars overlap; use a value below 0.5")
    a = span / 2.0
    delta = bulge * span
    cc = (a * a - delta * delta) / (2.0 * delta)     # arc centre beyond the side, arc radius cc + delta
    arc_r = cc + delta

    def d(x: np.ndarray) -> np.ndarray:               # inward offset of the side at position x (<= 0)
        return cc - np.sqrt(arc_r ** 2 - x ** 2)

    u = np.linspace(-1.0, 1.0, n + 1)
    U, V = np.meshgrid(u, u, indexing="xy")
    X = a * U + U * d(a * V)
    Y = a * V + V * d(a * U)
    Z = rise * (1.0 - (X ** 2 + Y ** 2) / (2.0 * a * a))
    v = np.stack([X.ravel(), Y.ravel(), np.maximum(Z.ravel(), 0.0)], axis=1)
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="xy")
    i, j = i.ravel(), j.ravel()
    corners = np.array([[-a, -a], [a, -a], [a, a], [-a, a]])
    dist = np.min(np.linalg.norm(v[:, None, :2] - corners[None], axis=2), axis=1)
    corner_cell = (np.minimum(i, n - i) <= 1) & (np.minimum(j, n - j) <= 1)
    supports = (dist <= frac * span) | corner_cell
    return _scene(_tri_mesh(v, _grid_triangles(n, n, radial=False)), supports, f"pillar_vault(n={n})",
                  params={"n": n, "span": span, "rise": rise, "pillar_radius_frac": frac, "bulge": bulge},
                  pillar_centres=np.c_[corners, np.zeros(4)].tolist())


# ---------------------------------------------------------------------------- registry
SHAPES: dict[str, Callable[..., Scene]] = {
    "disk": disk,
    "dome": dome,
    "concave_disk": concave_disk,
    "barrel_vault": barrel_vault,
    "cross_vault": cross_vault,
    "pillar_vault": pillar_vault,
}


def _barrel_resolution(n_vertices: int, kw: dict) -> dict:
    a = _positive("span", kw.get("span", 6.0)) / 2.0
    rise = _positive("rise", kw.get("rise", 2.0))
    length = _positive("length", kw.get("length", 10.0))
    c = _catenary_parameter(a, rise)
    ratio = 2.0 * c * math.sinh(a / c) / length          # arc length across / length along
    nx1 = max(3, round(math.sqrt(n_vertices * ratio)))
    ny1 = max(3, round(n_vertices / nx1))
    return {"nx": nx1 - 1, "ny": ny1 - 1}


def _square_resolution(even: bool, minimum: int) -> Callable[[int, dict], dict]:
    def resolve(n_vertices: int, kw: dict) -> dict:
        x = math.sqrt(n_vertices) - 1.0
        n = 2 * round(x / 2.0) if even else round(x)
        return {"n": max(minimum, n)}
    return resolve


# resolution parameter(s) of each shape, for a target vertex count
_RESOLUTION: dict[str, Callable[[int, dict], dict]] = {
    "disk": lambda nv, kw: {"n_rings": _rings_for(nv)},
    "dome": lambda nv, kw: {"rings": _rings_for(nv)},
    "concave_disk": lambda nv, kw: {"rings": max(3, _rings_for(nv))},
    "barrel_vault": _barrel_resolution,
    "cross_vault": _square_resolution(even=True, minimum=2),
    "pillar_vault": _square_resolution(even=False, minimum=4),
}


#: Most vertices :func:`make_shape` builds: a solve of that size already needs ~150 GiB
#: (:mod:`selfsupport.methods.memory`); ``shape:dome:1000000000`` was killed by the kernel at ~21 GB.
MAX_SHAPE_VERTICES = 10_000_000


def make_shape(name: str, *, n_vertices: int | None = None, **kw) -> Scene:
    """Build the registered shape ``name``; with ``n_vertices``, choose its resolution so
    that the mesh has about that many vertices (within 4% from 1,000 vertices up, 13% from
    150 up). Other keywords go to the factory.
    """
    factory = SHAPES.get(name)
    if factory is None:
        raise InputError(f"unknown shape {name!r}; known shapes: {', '.join(sorted(SHAPES))}")
    if n_vertices is not None:
        target = _count("n_vertices", n_vertices, 1)
        if target > MAX_SHAPE_VERTICES:  # refused before any array of that size is made
            raise InputError(f"{target:,} vertices is beyond the {MAX_SHAPE_VERTICES:,} a built-in shape is made with "
                             f"(building the mesh alone would need ~{target * 200 / 1024 ** 3:.0f} GiB); use fewer "
                             "vertices")
        res = _RESOLUTION[name](target, kw)
        clash = sorted(set(res) & set(kw))
        if clash:
            raise InputError(f"give either n_vertices or {', '.join(clash)} for shape {name!r}, not both")
        kw = {**kw, **res}
    try:
        inspect.signature(factory).bind(**kw)
    except TypeError as exc:
        raise InputError(f"bad parameters for shape {name!r}: {exc}; "
                         f"it takes {', '.join(inspect.signature(factory).parameters)}") from None
    return factory(**kw)
