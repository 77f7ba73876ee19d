"""Curvatures of a thrust network relative to its Airy stress surface (paper §2.3–2.4, §5).

With the stress Laplacian ``Δ_φ f(v_i) = Σ_j w_ij (f_j − f_i)`` (the same matrix as
:func:`formulations.equilibrium.stress_laplacian`), equation (3) reads
``Δ_φ s = A F`` and, per free vertex ``i`` (interior or on a free boundary; the quantities of
φ are taken on vertex ``i``'s branch of Φ, see :func:`~selfsupport.analysis.reciprocal.cover_cells`,
so they hold next to cuts around holes and interior supports too):

* ``Δ_φ φ (v_i) = 2 A*_i`` — twice the signed area of vertex ``i``'s cell in the reciprocal
  diagram (an identity of every network in horizontal equilibrium);
* ``Δ_φ s (v_i) = 2 A_i(Φ*, S*)`` — twice the mixed area of the reciprocal cell and the cell
  of the face gradients of ``s`` (an identity on triangle meshes);
* ``H_rel = Δ_φ s / Δ_φ φ`` (eq. 5), the mean curvature of S relative to Φ; on triangle meshes
  also ``A(Φ*, S*) / A(Φ*)`` (:attr:`Curvatures.H_rel_mixed`);
* ``K_Φ = A_i(Φ*, Φ*) / A_i = A*_i / A_i``, the Gaussian curvature of Φ (relative to the unit
  paraboloid ½(x² + y²), whose cells are the top-view areas), with ``A_i`` the top-view vertex
  area of :data:`~selfsupport.analysis.construction.AREA_RULES` (default mixed Voronoi);
* the discrete balance ``2 K_Φ H_rel = F_i`` (eq. 6) with ``F_i = (A_i F_i) / A_i`` the load
  **per unit top-view area**: the network stores nodal loads ``A_i F_i`` [N]. The area
  cancels, so :attr:`Curvatures.balance_residual` compares
  ``2 A*_i Δ_φ s / Δ_φ φ`` with the nodal load ``A_i F_i``; it vanishes exactly when (3) holds
  at ``i`` and the reciprocal cell closes (2). Where Φ is flat to round-off (``K_Φ = 0``,
  e.g. two collinear edges on a straight free boundary) ``H_rel`` is undefined and (6) is
  judged in the form ``2 A*_i Δ_φ s = Δ_φ φ · A_i F_i`` relative to the cell's scale
  (:data:`FLAT_TOL`, :attr:`Curvatures.flat`).

Relative principal curvatures and directions are the eigenvalues and eigenvectors of
``(∇²φ)⁻¹ ∇²s`` (``½ (κ₁ + κ₂)`` is the smooth counterpart of ``H_rel``), with both Hessians
estimated per vertex by a least-squares quadratic fit over the vertex's 2-ring in the top
view. :func:`write_vector_fields` exports them per face like the paper's ``-vf.txt``. The φ fit
still uses ``phi`` per vertex (one branch), so within two rings of a cut with a period the
Hessian of φ mixes branches (not yet on the cover).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from formulations.equilibrium import Topology, stress_laplacian
from selfsupport.analysis.airy import AiryResult, airy, face_planes_through, freeze_arrays
from selfsupport.analysis.construction import AREA_RULES
from selfsupport.analysis.reciprocal import cover_cells
from selfsupport.core.errors import InputError
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network
from selfsupport.io.atomic import atomic_write_text
from selfsupport.io.axes import to_file

#: A free vertex counts as flat (K_Φ = 0, eq. (6) reads 0 · ∞ = F) when 2 |A*_i| and |Δ_φ φ| are below
#: this fraction of its cell scale (Σ_j |w_ij| |e'_ij|)²: e.g. a straight free boundary, two collinear edges.
FLAT_TOL = 1e-10

__all__ = ["FLAT_TOL", "Curvatures", "curvatures", "vertex_hessians", "relative_principal", "face_principal_directions",
           "write_vector_fields"]


@dataclass(frozen=True, eq=False)
class Curvatures:
    """Per-vertex curvature quantities; ``NaN`` where a quantity is not defined (supports, see
    :attr:`defined`; also free boundary vertices for ``H_rel_mixed``, see :attr:`closed`)."""

    defined: np.ndarray  # free vertices (interior and free boundary): they must be in equilibrium
    closed: np.ndarray  # free vertices whose faces close around them (where H_rel_mixed is defined)
    flat: np.ndarray  # free vertices where Φ is flat to round-off (K_Φ = 0): H_rel undefined
    areas: np.ndarray  # top-view A_i
    load_density: np.ndarray  # F_i = loads / A_i [N/m²]
    laplacian_s: np.ndarray  # Δ_φ s
    laplacian_phi: np.ndarray  # Δ_φ φ
    reciprocal_areas: np.ndarray  # A*_i (signed)
    mixed_areas: np.ndarray  # A_i(Φ*, S*)
    H_rel: np.ndarray  # Δ_φ s / Δ_φ φ (eq. 5)
    H_rel_mixed: np.ndarray  # A(Φ*, S*) / A(Φ*), interior free vertices
    K_phi: np.ndarray  # A*_i / A_i
    balance: np.ndarray  # 2 K_Φ H_rel − F_i [N/m²]
    balance_residual: np.ndarray  # |2 K_Φ H_rel − F_i| / |F_i|
    identity_residual: np.ndarray  # |Δ_φ φ − 2 A*_i| / |Δ_φ φ|
    hessian_phi: np.ndarray | None  # (n, 2, 2)
    hessian_s: np.ndarray | None
    principal_curvatures: np.ndarray | None  # (n, 2), κ₁ ≤ κ₂
    principal_directions: np.ndarray | None  # (n, 2, 2): [i, k] unit top-view direction of κ_k

    def __post_init__(self) -> None:
        freeze_arrays(self)

    @property
    def max_balance_residual(self) -> float:
        r = self.balance_residual[np.isfinite(self.balance_residual)]
        return float(r.max()) if r.size else 0.0

    @property
    def max_identity_residual(self) -> float:
        r = self.identity_residual[np.isfinite(self.identity_residual)]
        return float(r.max()) if r.size else 0.0


# ---------------------------------------------------------------------------------- Hessians
def _ring_pairs(mesh: PolyMesh, rings: int) -> tuple[np.ndarray, np.ndarray]:
    e = mesh.edges
    n = mesh.n_vertices
    A = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()
    A = (A + sp.identity(n, format="csr")).astype(bool).astype(np.float64)
    R = A
    for _ in range(rings - 1):
        R = (R @ A).astype(bool).astype(np.float64)
    R = R.tocoo()
    keep = R.row != R.col
    return R.row[keep], R.col[keep]


def vertex_hessians(mesh: PolyMesh, fields: list[np.ndarray], *, rings: int = 2) -> list[np.ndarray]:
    """Per-vertex top-view Hessians of scalar vertex fields by least-squares quadratic fits.

    At vertex ``i``, ``f_j − f_i ≈ b·d + ½ dᵀ H d`` over the ``rings``-ring neighbours
    ``j`` (``d = x_j − x_i``, scaled by the local spacing for conditioning). Exact for quadratic
    fields. Returns one ``(n, 2, 2)`` array per field.
    """
    xy = mesh.vertices[:, :2]
    n = mesh.n_vertices
    i, j = _ring_pairs(mesh, rings)
    e = mesh.edges
    elen = np.linalg.norm(xy[e[:, 1]] - xy[e[:, 0]], axis=1)
    h = np.bincount(e.ravel(), weights=np.repeat(elen, 2), minlength=n) / np.maximum(np.bincount(e.ravel(), minlength=n), 1)
    h = np.where(h > 0, h, 1.0)
    d = (xy[j] - xy[i]) / h[i, None]
    mono = np.stack([d[:, 0], d[:, 1], 0.5 * d[:, 0] ** 2, d[:, 0] * d[:, 1], 0.5 * d[:, 1] ** 2], axis=1)
    M = np.empty((n, 5, 5))
    for a in range(5):
        for b in range(a, 5):
            M[:, a, b] = M[:, b, a] = np.bincount(i, weights=mono[:, a] * mono[:, b], minlength=n)
    Minv = np.linalg.pinv(M)  # pinv: vertices with too few neighbours get a minimum-norm fit
    out = []
    for f in fields:
        f = np.asarray(f, float)
        df = f[j] - f[i]
        r = np.stack([np.bincount(i, weights=mono[:, a] * df, minlength=n) for a in range(5)], axis=1)
        th = np.einsum("nab,nb->na", Minv, r)
        H = np.empty((n, 2, 2))
        H[:, 0, 0], H[:, 0, 1], H[:, 1, 1] = th[:, 2], th[:, 3], th[:, 4]
        H[:, 1, 0] = H[:, 0, 1]
        out.append(H / (h ** 2)[:, None, None])
    return out


def relative_principal(H_phi: np.ndarray, H_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues ``(…, 2)`` (ascending) and unit eigenvectors ``(…, 2, 2)`` (``[…, k]`` is
    the k-th direction) of ``H_phi⁻¹ H_s``; ``NaN`` where ``H_phi`` is singular or the
    eigenvalues are complex (Φ not convex there)."""
    # each matrix divided by its largest entry first (the directions do not change, the eigenvalues
    # scale by the ratio): products of entries of a network's size (heights of 1e200) then stay finite
    a = np.abs(H_phi).max(axis=(-1, -2))
    c = np.abs(H_s).max(axis=(-1, -2))
    a, c = np.where(a > 0, a, 1.0), np.where(c > 0, c, 1.0)
    ratio = c / a
    H_phi, H_s = H_phi / a[..., None, None], H_s / c[..., None, None]
    det = H_phi[..., 0, 0] * H_phi[..., 1, 1] - H_phi[..., 0, 1] * H_phi[..., 1, 0]
    scale = np.abs(H_phi).max(axis=(-1, -2)) ** 2
    ok = np.abs(det) > 1e-12 * np.maximum(scale, 1e-300)
    inv = np.empty_like(H_phi)
    inv[..., 0, 0], inv[..., 1, 1] = H_phi[..., 1, 1], H_phi[..., 0, 0]
    inv[..., 0, 1], inv[..., 1, 0] = -H_phi[..., 0, 1], -H_phi[..., 1, 0]
    inv /= np.where(ok, det, 1.0)[..., None, None]
    Mx = inv @ H_s
    tr = Mx[..., 0, 0] + Mx[..., 1, 1]
    dt = Mx[..., 0, 0] * Mx[..., 1, 1] - Mx[..., 0, 1] * Mx[..., 1, 0]
    disc = tr ** 2 / 4 - dt
    ok &= disc >= -1e-12 * np.maximum(tr ** 2, 1e-300)
    root = np.sqrt(np.maximum(disc, 0.0))
    lam = np.stack([tr / 2 - root, tr / 2 + root], axis=-1)
    vecs = np.empty(lam.shape + (2,))
    for k in range(2):
        l_ = lam[..., k]
        v1 = np.stack([Mx[..., 0, 1], l_ - Mx[..., 0, 0]], axis=-1)
        v2 = np.stack([l_ - Mx[..., 1, 1], Mx[..., 1, 0]], axis=-1)
        n1, n2 = np.linalg.norm(v1, axis=-1), np.linalg.norm(v2, axis=-1)
        v = np.where((n1 >= n2)[..., None], v1, v2)
        nv = np.linalg.norm(v, axis=-1)
        # umbilic (M a multiple of I): every direction is principal; take the axes
        axis = np.zeros_like(v)
        axis[..., k] = 1.0
        v = np.where((nv > 1e-12 * np.maximum(np.abs(Mx).max(axis=(-1, -2)), 1e-300))[..., None],
                     v / np.where(nv > 0, nv, 1.0)[..., None], axis)
        vecs[..., :, k] = v
    lam *= ratio[..., None]
    lam[~ok] = np.nan
    vecs[~ok] = np.nan
    return lam, vecs


# ---------------------------------------------------------------------------------- main
def curvatures(network: Network, airy_result: AiryResult | None = None, *, areas: str = "voronoi",
               directions: bool = True, rings: int = 2) -> Curvatures:
    """Stress Laplacian, H_rel, K_Φ, the balance (6) and relative principal directions.

    Parameters
    ----------
    network
        The network (positions, weights, nodal loads ``A_i F_i``, supports).
    airy_result
        Its :func:`~selfsupport.analysis.airy` result (computed when not given).
    areas
        Top-view vertex-area rule ``A_i`` (:data:`~selfsupport.analysis.construction.AREA_RULES`),
        used for ``K_Φ`` and for ``F_i = loads / A_i``; eq. (6) does not depend on it.
    directions
        Also estimate Hessians and relative principal directions (2-ring quadratic fits).
    rings
        Neighbourhood of the quadratic fits.
    """
    network = getattr(network, "network", network)
    res = airy(network) if airy_result is None else airy_result
    mesh = network.mesh
    n = mesh.n_vertices
    try:
        A = AREA_RULES[areas](mesh)
    except KeyError:
        raise InputError(f"unknown area rule {areas!r}; choose one of {', '.join(AREA_RULES)}") from None
    top = Topology.build(n, mesh.edges, network.supports)
    L = stress_laplacian(top, network.weights)
    s = mesh.vertices[:, 2]
    lap_s = L @ s
    xy = mesh.vertices[:, :2]
    grad_s, _, _ = face_planes_through(mesh, xy, s)
    cells = cover_cells(res, grad_s)
    lap_phi, a_star, a_mix = cells.laplacian_phi, cells.areas, cells.mixed_areas
    defined = ~network.supports
    closed = defined & ~mesh.boundary_vertex_mask
    # cell scale: (perimeter of the force polygon)² bounds 4π |A*_i| and sets the round-off of both sums
    e = mesh.edges
    fl = np.abs(network.weights) * np.linalg.norm(xy[e[:, 1]] - xy[e[:, 0]], axis=1)
    cell_scale = np.bincount(e.ravel(), weights=np.repeat(fl, 2), minlength=n) ** 2
    flat = defined & (2 * np.abs(a_star) <= FLAT_TOL * cell_scale) & (np.abs(lap_phi) <= FLAT_TOL * cell_scale)
    sharp = defined & ~flat
    nan = np.full(n, np.nan)
    loads = network.loads
    with np.errstate(divide="ignore", invalid="ignore"):
        H = np.where(sharp, lap_s / lap_phi, nan)
        H_mixed = np.where(closed & ~flat, a_mix / a_star, nan)
        K = np.where(defined, a_star / A, nan)
        F = loads / A
        bal = np.where(sharp, 2 * K * H - F, nan)
        # where Φ is flat (K_Φ = 0, H_rel = ∞) eq. (6) is judged as 2 A*_i Δs = Δφ A_i F_i
        bal_res = np.where(sharp, np.abs(2 * a_star * lap_s / lap_phi - loads) / np.abs(loads),
                           np.abs(2 * a_star * lap_s - lap_phi * loads) / (cell_scale * np.abs(loads)))
        bal_res = np.where(defined, bal_res, nan)
        ident = np.where(sharp, np.abs(lap_phi - 2 * a_star) / np.abs(lap_phi),
                         np.abs(lap_phi - 2 * a_star) / cell_scale)
        ident = np.where(defined, ident, nan)
    Hp = Hs = kap = dirs = None
    if directions:
        Hp, Hs = vertex_hessians(mesh, [res.phi, s], rings=rings)
        kap, dirs = relative_principal(Hp, Hs)
    return Curvatures(defined=defined, closed=closed, flat=flat, areas=A, load_density=F, laplacian_s=lap_s, laplacian_phi=lap_phi,
                      reciprocal_areas=np.where(defined, a_star, nan), mixed_areas=np.where(defined, a_mix, nan),
                      H_rel=H, H_rel_mixed=H_mixed, K_phi=K, balance=bal, balance_residual=bal_res,
                      identity_residual=ident, hessian_phi=Hp, hessian_s=Hs, principal_curvatures=kap,
                      principal_directions=dirs)


def face_principal_directions(network: Network, curv: Curvatures) -> np.ndarray:
    """``(F, 2, 3)``: per face, the two relative principal directions as 3D unit vectors
    tangent to the face (the original tool's layout): the face's mean vertex Hessians are
    decomposed, and each top-view direction ``u`` is lifted to ``(u, ∇s_f · u)``."""
    if curv.hessian_phi is None:
        raise InputError("the curvatures were computed without directions; call curvatures(..., directions=True)")
    network = getattr(network, "network", network)
    mesh = network.mesh
    face_of, _, _ = mesh.corner_data
    fv = mesh.face_vertices
    sizes = mesh.face_sizes[:, None, None]
    Hp = np.zeros((mesh.n_faces, 2, 2))
    Hs = np.zeros((mesh.n_faces, 2, 2))
    np.add.at(Hp, face_of, curv.hessian_phi[fv])
    np.add.at(Hs, face_of, curv.hessian_s[fv])
    _, vecs = relative_principal(Hp / sizes, Hs / sizes)
    grad_s, _, _ = face_planes_through(mesh, mesh.vertices[:, :2], mesh.vertices[:, 2])
    out = np.empty((mesh.n_faces, 2, 3))
    for k in range(2):
        u = vecs[:, :, k]
        u3 = np.c_[u, np.einsum("fi,fi->f", grad_s, u)]
        out[:, k] = u3 / np.linalg.norm(u3, axis=1, keepdims=True)
    return out


def write_vector_fields(path: str | Path, network: Network, curv: Curvatures, *, up: str = "z") -> None:
    """Write the per-face relative principal directions like the paper's ``-vf.txt``: one line
    per face, ``u_x u_y u_z v_x v_y v_z`` in the file's axes (``up="-y"`` for the paper's
    convention), atomically. ``u`` is the direction of κ₂ (the larger relative curvature),
    ``v`` that of κ₁: the order of the published ``lilium-n-vf.txt`` (whose tool measured
    heights downwards, which reverses the order of the eigenvalues). Faces without real
    directions (Φ not convex there) get ``nan``."""
    d = face_principal_directions(network, curv)
    u = to_file(d[:, 1], up)
    v = to_file(d[:, 0], up)
    rows = np.c_[u, v]
    atomic_write_text(path, (" ".join(f"{x:.9g}" for x in r) + "\n" for r in rows.tolist()))
