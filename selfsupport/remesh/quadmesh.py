"""A smooth frame field for an integer-grid (seamless, MIQ-style) quad remesh (for :mod:`.remesh`).

The relative principal directions of a thrust network (:func:`.remesh.principal_line_fields`)
are a *frame* field: two line fields, not orthogonal in general, noisy where the two relative
principal curvatures are close (every direction is principal at an umbilic), and with many
singularities (the paper's lilium: 37 singular vertices, where its published quad mesh has one
pole). A quad mesh along them needs a field with few singularities, aligned with the boundary
so that the boundary is a mesh line. This module smooths the field; :mod:`.param` then finds the
integer-grid parametrization (cut graph, least squares with integer jumps across the cut,
singular vertices and boundary runs on integers, greedy rounding) and :mod:`.remesh` extracts
the quads from its integer iso-lines.

A frame ``F = [d1 d2]`` (unit columns at angles ``a1``, ``a2``) is written as a cross (two
orthogonal lines at ``mid ∓ 45°``, ``mid`` the bisector) times a symmetric stretch ``S``
(``F = S C``, Panozzo et al. 2014, *Frame fields*):
``S = R(mid) diag(cos(g/2), sin(g/2)) R(mid)ᵀ / cos 45°`` with ``g = a2 − a1``. The cross is
smoothed as the complex number ``z = exp(4iθ)`` (``θ`` the angle of either line: the four
choices give the same ``z``), ``S`` component by component (relabelling the frame's lines
leaves ``S`` unchanged). Both minimise, per triangle ``t`` and interior edge ``e = (s, t)``,

    Σ_e w_e |x_s − x_t|²  +  ℓ⁻² Σ_t A_t c_t |x_t − x⁰_t|²       (w_e = |e| / |c_s − c_t|)

(a discrete ``∫|∇x|² + ℓ⁻² ∫ c |x − x⁰|²``: ``ℓ`` the smoothing length, ``c_t`` the
confidence of the data), with the boundary triangles' crosses held on their boundary edge's
direction (``S = I`` there) when ``align_boundary``. A large ``ℓ`` gives the smoothest field
(the fewest singularities, ±1/4 each), a small one follows the data. The linear smoothing
leaves a zero of high order where the data turn round a point (a dome's apex: ``z ~ (x + iy)⁴``,
index +1 in one place, which no quad mesh vertex has); a few steps of diffusion and
normalisation (:func:`_relax`) split it into quarter turns that repel each other.

Example: a square (its corners jittered by 1e-3) with a noisy axis-aligned field comes back
aligned with the axes, its largest angle to them from 40° to under half a degree.

>>> import numpy as np
>>> from scipy.spatial import Delaunay
>>> g = np.linspace(0.0, 1.0, 7)
>>> xy = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2) + 1e-3 * np.sin(np.arange(49))[:, None]
>>> tris = Delaunay(xy).simplices
>>> rng = np.random.default_rng(0)
>>> ang = 0.3 * rng.standard_normal(len(tris))
>>> F0 = np.stack([np.c_[np.cos(ang), np.sin(ang)], np.c_[-np.sin(ang), np.cos(ang)]], axis=2)
>>> F = smooth_frames(xy, tris, F0, length=10.0)
>>> off = lambda F: float(np.degrees(np.abs(np.angle(frame_to_cross(F)[0]) / 4)).max())
>>> round(off(F0)), off(F) < 0.5
(40, True)
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from selfsupport.core.errors import InputError
from selfsupport.remesh.param import _gradients, _interior_edges, _vertex_fans

__all__ = ["frame_to_cross", "cross_to_frame", "smooth_frames", "cross_indices", "SMOOTHING"]

#: Default smoothing length ``ℓ`` as a fraction of the top view's bounding-box diagonal.
SMOOTHING = 0.05
#: Steps of the Ginzburg–Landau relaxation of the smoothed cross field (:func:`smooth_frames`).
RELAX = 30
#: Smallest relative weight of a triangle's data (the confidence where the relative principal
#: curvatures are equal, so that a field is still defined there).
MIN_CONFIDENCE = 1e-3


def frame_to_cross(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(z, S)``: per frame ``(k, 2, 2)`` (unit columns) the cross as ``exp(4iθ)`` and the stretch
    ``(k, 2, 2)`` with ``F ≈ S C`` up to the columns' order and signs (module docstring)."""
    a1 = np.arctan2(F[:, 1, 0], F[:, 0, 0])
    a2 = np.arctan2(F[:, 1, 1], F[:, 0, 1])
    g = (a2 - a1) % np.pi  # the second line's angle from the first, in [0, π)
    mid = a1 + 0.5 * g
    z = np.exp(4j * (mid - 0.25 * np.pi))
    c, s = np.cos(mid), np.sin(mid)
    R = np.stack([np.c_[c, s], np.c_[-s, c]], axis=2)  # columns (c, s), (−s, c)
    lam = np.c_[np.cos(0.5 * g), np.sin(0.5 * g)] * np.sqrt(2.0)
    S = np.einsum("kij,kj,klj->kil", R, lam, R)
    return z, S


def cross_to_frame(z: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Frames ``(k, 2, 2)`` (unit columns ``S c1``, ``S c2``, the cross ``c1 ⊥ c2`` at ``arg(z) / 4``)."""
    th = np.angle(z) / 4.0
    C = np.stack([np.c_[np.cos(th), np.sin(th)], np.c_[-np.sin(th), np.cos(th)]], axis=2)
    F = S @ C
    return F / np.linalg.norm(F, axis=1, keepdims=True)


def _boundary_edges(xy: np.ndarray, tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per boundary edge its triangle and its direction's angle."""
    a = tris[:, [0, 1, 2]].ravel()
    b = tris[:, [1, 2, 0]].ravel()
    t = np.repeat(np.arange(len(tris)), 3)
    key = np.minimum(a, b) * (int(tris.max()) + 1) + np.maximum(a, b)
    uniq, cnt = np.unique(key, return_counts=True)
    once = np.isin(key, uniq[cnt == 1])
    e = xy[b[once]] - xy[a[once]]
    return t[once], np.arctan2(e[:, 1], e[:, 0])


def _relax(L: sp.csr_matrix, M: np.ndarray, area: np.ndarray, z: np.ndarray, z0: np.ndarray, zb: np.ndarray,
           free: np.ndarray, fx: np.ndarray, steps: int, tau: float) -> np.ndarray:
    """``steps`` steps of diffusion (time ``tau``) then normalisation (the MBO scheme for the
    Ginzburg–Landau energy, Viertel & Osting 2019), the data term kept: singularities of the same
    sign repel, so the zero of high order that the linear smoothing leaves where the data turn
    round a point (four quarter turns at a dome's apex) comes apart into quarter turns spread
    over the domain, as in a quad mesh of a disk."""
    A = (sp.diags(area) + tau * (L + sp.diags(M))).tocsr()
    Aff = A[free][:, free].tocsc()
    lu = spla.splu(Aff)
    Afx = A[free][:, fx]
    for _ in range(steps):
        u = z / np.maximum(np.abs(z), 1e-300)
        rhs = area[free] * u[free] + tau * M[free] * z0[free] - Afx @ zb[fx]
        z = zb.copy()
        z[free] = lu.solve(np.ascontiguousarray(rhs.real)) + 1j * lu.solve(np.ascontiguousarray(rhs.imag))
    return z


def smooth_frames(xy: np.ndarray, tris: np.ndarray, frames: np.ndarray, *, length: float,
                  confidence: np.ndarray | None = None, align_boundary: bool = True, relax: int = RELAX,
                  step: float | None = None) -> np.ndarray:
    """A smooth frame field ``(m, 2, 2)`` per triangle near ``frames`` (module docstring).

    Parameters
    ----------
    xy, tris
        The top-view triangulation ``(n, 2)``, ``(m, 3)``.
    frames
        ``(m, 2, 2)`` per triangle two unit directions (columns); signs and order do not matter.
    length
        Smoothing length ``ℓ`` [m]: the data term's weight is ``ℓ⁻²`` per unit area.
    confidence
        ``(m,)`` weight of each triangle's data in ``[0, 1]`` (default 1).
    align_boundary
        Hold the crosses of boundary triangles on the direction of their boundary edge (the
        mean of the fourfold-angle vectors where a triangle has two), with ``S = I``.

    relax
        Steps of the Ginzburg–Landau relaxation after the linear smoothing (:func:`_relax`).
    step
        Its diffusion time per step [m²] (default: the square of the mean edge length).

    Returns
    -------
    numpy.ndarray
        ``(m, 2, 2)`` unit columns.
    """
    xy = np.asarray(xy, float)
    tris = np.asarray(tris, np.int64)
    m = len(tris)
    if not (np.isfinite(length) and length > 0):
        raise InputError(f"the smoothing length must be a positive number, got {length!r}")
    if not np.all(np.isfinite(frames)):
        raise InputError("the frame field has undefined directions; fill them before smoothing")
    z0, S0 = frame_to_cross(np.asarray(frames, float))
    _, area = _gradients(xy, tris)
    conf = np.ones(m) if confidence is None else np.clip(np.asarray(confidence, float), MIN_CONFIDENCE, 1.0)
    edges, et, _ = _interior_edges(tris)
    cen = xy[tris].mean(axis=1)
    w = np.linalg.norm(xy[edges[:, 1]] - xy[edges[:, 0]], axis=1) / np.maximum(
        np.linalg.norm(cen[et[:, 0]] - cen[et[:, 1]], axis=1), 1e-300)
    L = sp.coo_matrix((np.r_[w, w, -w, -w], (np.r_[et[:, 0], et[:, 1], et[:, 0], et[:, 1]],
                                             np.r_[et[:, 0], et[:, 1], et[:, 1], et[:, 0]])), shape=(m, m)).tocsr()
    M = area * conf / length ** 2
    fixed = np.zeros(m, bool)
    zb = np.zeros(m, complex)
    if align_boundary:
        bt, ang = _boundary_edges(xy, tris)
        np.add.at(zb, bt, np.exp(4j * ang))
        fixed[bt] = True
        zb[fixed] /= np.maximum(np.abs(zb[fixed]), 1e-300)
    free = np.flatnonzero(~fixed)
    fx = np.flatnonzero(fixed)
    if step is None:
        step = float(np.mean(np.linalg.norm(xy[edges[:, 1]] - xy[edges[:, 0]], axis=1)) ** 2) if len(edges) else 1.0
    A = (L + sp.diags(M)).tocsr()
    Aff = A[free][:, free].tocsc()
    lu = spla.splu(Aff + 1e-14 * float(Aff.diagonal().mean()) * sp.identity(len(free), format="csc"))

    Afx = A[free][:, fx]

    def solve(x0: np.ndarray, xb: np.ndarray) -> np.ndarray:
        out = xb.copy()
        rhs = M[free] * x0[free] - Afx @ xb[fx]
        if np.iscomplexobj(rhs):  # (splu of a real matrix solves real right-hand sides)
            out[free] = lu.solve(np.ascontiguousarray(rhs.real)) + 1j * lu.solve(np.ascontiguousarray(rhs.imag))
        else:
            out[free] = lu.solve(rhs)
        return out

    z = solve(z0, zb)
    if relax > 0 and free.size:
        z = _relax(L, M, area, z, z0, zb, free, fx, relax, step)
    I2 = np.broadcast_to(np.eye(2), (m, 2, 2))
    Sb = np.where(fixed[:, None, None], I2, 0.0)
    S = np.empty((m, 2, 2))
    for i, j in ((0, 0), (0, 1), (1, 1)):
        S[:, i, j] = solve(S0[:, i, j], Sb[:, i, j])
    S[:, 1, 0] = S[:, 0, 1]
    # z = 0 only at isolated points; a triangle whose z vanishes to round-off takes its data's cross
    small = np.abs(z) < 1e-12
    z[small] = z0[small]
    # a stretch that lost definiteness in the blend (it never should: a mean of SPD matrices) is I
    det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] ** 2
    S[(det <= 0) | (S[:, 0, 0] <= 0)] = np.eye(2)
    return cross_to_frame(z, S)


def cross_indices(xy: np.ndarray, tris: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """Per vertex the index of the frames' cross field around it (a multiple of 1/4; 0 on the
    boundary): the turning of ``θ`` around the vertex's triangles, each step the smallest of the
    four choices, over 2π."""
    xy = np.asarray(xy, float)
    tris = np.asarray(tris, np.int64)
    z, _ = frame_to_cross(np.asarray(frames, float))
    th = np.angle(z) / 4.0
    n = len(xy)
    _, _, bnd = _interior_edges(tris)
    fans = _vertex_fans(n, xy, tris)  # triangles around each vertex in angular order
    out = np.zeros(n)
    for i in np.flatnonzero(~bnd):
        f = fans[i]
        if len(f) < 3:
            continue
        d = np.diff(th[np.r_[f, f[:1]]])
        d = (d + 0.25 * np.pi) % (0.5 * np.pi) - 0.25 * np.pi
        out[i] = d.sum() / (2 * np.pi)
    return np.round(out * 4) / 4
